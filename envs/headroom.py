"""How much room a tuner has: ``crowdsim headroom`` (issue 15's "headroom first").

On held-out sequences (:func:`envs.heldout.heldout_episodes`: ``seeds`` per family, never
tuned on) a fixed set of ``M`` candidate settings -- the tracker's defaults (action 0) and
``M - 1`` scrambled Sobol points of its :class:`envs.param_space.ParamSpace` -- is scored
three ways, all as acc@T (points within ``threshold_px`` of the same person, pooled over the
frames after the first):

* **(a) global static**: the one candidate with the best mean over all sequences, used
  everywhere; what one static tuning for every scene can reach;
* **(b) per-family static**: in each family, its own best candidate; what a scene-aware
  tuner that picks one setting per scene can reach;
* **(c) per-segment oracle**: the tracker runs in segments of ``k_frames``; before each
  segment its state is copied once per candidate, each copy tracks the segment with that
  candidate, and the copy with the best accuracy on the segment *by the ground truth* goes
  on. What an adaptive policy switching among the same candidates every ``k_frames`` frames
  could reach; greedy, so not a strict bound: where a choice's effect outlasts its segment
  (a track lost or kept), it can end below (b).

``(b) - (a)`` is the room for scene-aware tuning, ``(c) - (b)`` the extra room for
adaptation. Candidates and the choice of (a) and (b) come from the held-out sequences
themselves: these are what choosing could reach, not results a tuner has earned.
"""

from __future__ import annotations

import copy
from collections.abc import Callable, Mapping
from typing import Any

import numpy as np

from crowdsim.checks import require_number
from envs.param_space import ParamSpace, candidate_actions
from envs.tracker_tuning import track_segment

HEADROOM_FILES: tuple[str, ...] = ("headroom.json", "headroom.md")


class _Counts:
    """Hits and scored points of one run."""

    def __init__(self) -> None:
        self.hits = 0
        self.total = 0

    def add(self, hits: int, total: int) -> None:
        self.hits += hits
        self.total += total

    @property
    def acc(self) -> float:
        return 100.0 * self.hits / self.total if self.total else 0.0


def sequence_headroom(
    seq: Any,
    tracker: str,
    space: ParamSpace,
    actions: np.ndarray,
    k_frames: int = 25,
    threshold_px: float = 5.0,
) -> dict[str, Any]:
    """Static accuracy of every candidate and the per-segment oracle on one sequence.

    Returns ``{"static": [acc per candidate], "oracle": acc, "oracle_choices": [candidate
    index per segment], "points": scored points}`` (acc in %).
    """
    from envs.tracker_tuning import make_tuned_tracker

    require_number("headroom", "k_frames", k_frames, lo=1, integer=True)
    frames = list(seq.frames())
    gt_ids, gt = seq.gt_points()
    gt_ids, gt = np.asarray(gt_ids, np.int64), np.asarray(gt, np.float64)
    (ids0, pts0), births = seq.births()
    births = dict(births)
    tpl = int(seq.template_size)
    n = len(frames)

    def fresh(action: np.ndarray) -> Any:
        trk = make_tuned_tracker(tracker, space.to_params(action))
        trk.init(frames[0], ids0, pts0, tpl)
        return trk

    static = []
    for a in actions:
        c = _Counts()
        c.add(*track_segment(fresh(a), frames, births, gt_ids, gt, 1, n, threshold_px))
        static.append(c.acc)
    oracle, choices = _Counts(), []
    trk = fresh(actions[0])
    for start in range(1, n, k_frames):
        stop = min(start + k_frames, n)
        best = None
        for i, a in enumerate(actions):
            branch = copy.deepcopy(trk)
            branch.set_params(space.to_params(a))
            hits, total = track_segment(
                branch, frames, births, gt_ids, gt, start, stop, threshold_px
            )
            if best is None or hits > best[0]:
                best = (hits, total, i, branch)
        oracle.add(best[0], best[1])
        choices.append(best[2])
        trk = best[3]
    return {"static": static, "oracle": oracle.acc, "oracle_choices": choices}


def measure_headroom(
    objective: Any,
    seeds: int,
    candidates: int = 17,
    k_frames: int = 25,
    seed: int = 0,
    progress: bool = True,
    log: Callable[[str], None] = print,
) -> dict[str, Any]:
    """(a), (b), (c) per family and overall on ``seeds`` held-out sequences per family of
    ``objective`` (an :class:`envs.tuners.Objective`: suite or scenarios, tracker, frames,
    threshold). See the module docstring."""
    from crowdsim.progress import progress_bar
    from envs.heldout import heldout_count, heldout_episodes

    require_number("headroom", "seeds", seeds, lo=1, integer=True)
    space = objective.space()
    actions = candidate_actions(space, candidates, seed)
    per_seq: list[dict[str, Any]] = []
    skipped: list[str] = []
    bar = progress_bar(
        total=heldout_count(objective, seeds), desc="headroom", unit="seq", enabled=progress
    )
    for family, seq, _ in heldout_episodes(objective, seeds, skipped):
        r = sequence_headroom(
            seq, objective.tracker, space, actions, k_frames, objective.threshold_px
        )
        per_seq.append({"family": family, "sequence": seq.name, **r})
        bar.update(1)
    bar.close()
    if skipped:
        log(f"headroom: passed over {len(skipped)} sequences with nobody in view")
    static = np.array([r["static"] for r in per_seq])  # (sequences, candidates)
    global_best = int(np.argmax(static.mean(axis=0)))
    families: dict[str, Any] = {}
    for fam in dict.fromkeys(r["family"] for r in per_seq):
        rows = [i for i, r in enumerate(per_seq) if r["family"] == fam]
        fam_static = static[rows]
        fam_best = int(np.argmax(fam_static.mean(axis=0)))
        a = fam_static[:, global_best]
        b = fam_static[:, fam_best]
        c = np.array([per_seq[i]["oracle"] for i in rows])
        families[fam] = {
            "n": len(rows),
            "defaults": float(fam_static[:, 0].mean()),
            "a_global_static": float(a.mean()),
            "b_family_static": float(b.mean()),
            "c_oracle": float(c.mean()),
            "b_minus_a": float((b - a).mean()),
            "c_minus_b": float((c - b).mean()),
            "family_best": space.values(actions[fam_best]),
        }
    oracle = np.array([r["oracle"] for r in per_seq])
    fam_b = np.array([families[r["family"]]["b_family_static"] for r in per_seq])
    return {
        "tracker": objective.tracker,
        "objective": objective.describe(),
        "seeds_per_family": seeds,
        "k_frames": k_frames,
        "threshold_px": objective.threshold_px,
        "candidates": [space.values(a) for a in actions],
        "global_best": space.values(actions[global_best]),
        "overall": {
            "defaults": float(static[:, 0].mean()),
            "a_global_static": float(static[:, global_best].mean()),
            "b_family_static": float(fam_b.mean()),
            "c_oracle": float(oracle.mean()),
        },
        "families": families,
        "sequences": per_seq,
    }


def headroom_table(doc: Mapping[str, Any]) -> str:
    """Markdown: per family and overall, acc@T of the defaults, (a), (b), (c) and the rooms."""
    t = doc["threshold_px"]
    lines = [
        f"# Headroom of {doc['tracker']} (acc@{t:g} %, {doc['seeds_per_family']} held-out "
        f"sequences per family, {len(doc['candidates'])} candidates, segments of "
        f"{doc['k_frames']} frames)",
        "",
        "| family | n | defaults | (a) global static | (b) family static | (c) segment oracle "
        "| (b)-(a) | (c)-(b) |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for fam, r in doc["families"].items():
        lines.append(
            f"| {fam} | {r['n']} | {r['defaults']:.1f} | {r['a_global_static']:.1f} | "
            f"{r['b_family_static']:.1f} | {r['c_oracle']:.1f} | {r['b_minus_a']:+.1f} | "
            f"{r['c_minus_b']:+.1f} |"
        )
    o = doc["overall"]
    lines.append(
        f"| all | {len(doc['sequences'])} | {o['defaults']:.1f} | {o['a_global_static']:.1f} | "
        f"{o['b_family_static']:.1f} | {o['c_oracle']:.1f} | "
        f"{o['b_family_static'] - o['a_global_static']:+.1f} | "
        f"{o['c_oracle'] - o['b_family_static']:+.1f} |"
    )
    best = ", ".join(f"{k}={v:.3g}" for k, v in doc["global_best"].items())
    lines += ["", f"(a) uses {best}.", ""]
    return "\n".join(lines)


def _is_headroom(doc: Any) -> bool:
    return isinstance(doc, dict) and {"families", "candidates", "k_frames"} <= set(doc)


def check_headroom_out(out: Any, flag: str = "--out") -> None:
    """Refuse a folder whose ``headroom.json`` / ``headroom.md`` this program cannot prove it
    wrote, before any work (see :mod:`envs.outputs`)."""
    from envs.outputs import check_outputs

    check_outputs(
        out, HEADROOM_FILES[0], HEADROOM_FILES[1:], _is_headroom, "crowdsim headroom", flag=flag
    )


def write_headroom(doc: Mapping[str, Any], out: Any) -> dict[str, str]:
    """Write ``headroom.json`` (with the table's SHA-256) and ``headroom.md``, atomically."""
    from envs.outputs import write_outputs

    paths = write_outputs(
        out, "headroom.json", doc, {"headroom.md": lambda p: p.write_text(headroom_table(doc))}
    )
    return {name: str(p) for name, p in paths.items()}
