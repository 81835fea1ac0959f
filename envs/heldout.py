"""Held-out scoring: static parameter sets and adaptive policies on sequences never tuned on.

What the tuning evidence rests on. :func:`heldout_episodes` draws ``seeds`` held-out sequences
**per family** (a built-in suite's sequence re-seeded ``seeds`` times, or a scenario
distribution's episodes until every scenario family has ``seeds``) from seed streams disjoint
from the tuning stream. :func:`evaluate_heldout` tracks each with every parameter set (the
paper defaults, a ``best_params.json``) and every policy (a ``model.zip`` of ``crowdsim
train``) and reports acc@5, acc@15, HOTA, MOTA and IDF1 per sequence, per family and overall
(mean and standard deviation). :func:`plot_heldout` draws the per-family means as a PNG and
:func:`heldout_table` as Markdown.
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping
from typing import Any

import numpy as np

from crowdsim.checks import require_number
from envs.episodes import make_episodes, shows_someone

HELDOUT_SEED = 1
"""First held-out stream (scenario distributions) or re-seed offset (built-in suites); tuning
uses stream 0, held-out seed ``j`` uses ``HELDOUT_SEED + j``."""

METRICS = ("acc@5", "acc@15", "hota", "mota", "idf1")
"""Scores kept per sequence (``acc@T`` in % of points within T px; the rest TrackEval's)."""

_MAX_DRAWS_PER_SEED = 40
"""A scenario family that has not come up after ``40 * families * seeds`` draws is missing."""


def heldout_episodes(
    objective: Any, seeds: int, skipped: list[str] | None = None
) -> Iterator[tuple[str, Any, Any]]:
    """``(family, sequence, spec)`` of the held-out sequences of ``objective``, built lazily.

    Built-in suite: each tuned sequence (``objective.only``, default all) re-seeded with
    offsets ``HELDOUT_SEED .. HELDOUT_SEED + seeds - 1``; the family is the sequence's name.
    Scenario distribution: episodes of stream ``HELDOUT_SEED`` until each family (scenario,
    or event kind for a non-stationary distribution) has ``seeds`` with someone to track (an
    episode whose camera sees nobody is passed over and its name appended to ``skipped``).
    Suite folder: the ``objective.heldout_only`` sequences once each (a folder cannot be
    re-seeded).
    """
    require_number("heldout", "seeds", seeds, lo=1, integer=True)
    if objective.folder:
        src = objective.episodes(heldout=True)
        for i, name in enumerate(src.names()):
            yield name, src.episode(i), src.spec(i)
        return
    if objective.suite is not None:
        for j in range(seeds):
            src = make_episodes(
                suite=objective.suite,
                only=objective.only or None,
                frames=objective.frames,
                seed=HELDOUT_SEED + j,
            )
            for i in range(len(src)):
                yield src.spec(i).name, src.episode(i), src.spec(i)
        return
    src = objective.episodes(heldout=True)
    families = src.dist.families
    counts = dict.fromkeys(families, 0)
    for i in range(_MAX_DRAWS_PER_SEED * len(families) * seeds):
        spec = src.spec(i)
        family = src.dist.family(spec)
        if counts.get(family, seeds) >= seeds:
            continue
        seq = src.episode(i)
        if not shows_someone(seq):
            if skipped is not None:
                skipped.append(spec.name)
            continue
        counts[family] += 1
        yield family, seq, spec
        if all(c >= seeds for c in counts.values()):
            return
    missing = [f for f, c in counts.items() if c < seeds]
    raise ValueError(
        f"held-out: scenario families {missing} gave fewer than {seeds} sequences with "
        "someone in view (more agents or a higher density would help)"
    )


def heldout_count(objective: Any, seeds: int) -> int:
    """How many sequences :func:`heldout_episodes` yields (without building any)."""
    if objective.suite is None:
        return len(objective.episodes(heldout=True).dist.families) * seeds
    if objective.folder:
        return len(objective.episodes(heldout=True))
    return len(make_episodes(suite=objective.suite, only=objective.only or None)) * seeds


def _policy_runner(policy: Any) -> Any:
    """``source -> (tracker, controlled source)`` for a ``model.zip`` path (loaded once) or a
    loaded ``(model, meta)`` pair."""
    from envs.training import load_policy, policy_tracker

    model, meta = policy if isinstance(policy, tuple) else load_policy(policy)

    def make(source: Any) -> tuple[Any, Any]:
        trk, ctl, _ = policy_tracker(source, model, meta)
        return trk, ctl

    return make


def _stats(values: list[float]) -> dict[str, float]:
    return {"mean": float(np.mean(values)), "std": float(np.std(values)), "n": len(values)}


def evaluate_heldout(
    objective: Any,
    param_sets: Mapping[str, Any],
    seeds: int,
    policies: Mapping[str, Any] | None = None,
    metrics: str = "full",
    progress: bool = False,
) -> dict[str, Any]:
    """Score parameter sets and policies on held-out sequences (never seen while tuning).

    Parameters
    ----------
    objective : envs.tuners.Objective
        Where the sequences come from (its tracker, frames and threshold too).
    param_sets : mapping
        ``label -> params`` of ``objective.tracker`` (e.g. ``{"defaults": ..., "tuned": ...}``).
    seeds : int
        Held-out sequences per family (see :func:`heldout_episodes`).
    policies : mapping, optional
        ``label -> model.zip`` of ``crowdsim train`` (or a ``(model, meta)`` pair of
        :func:`envs.training.load_policy`): the policy sets the parameters every ``k_frames``
        frames, deterministically, as ``crowdsim track --policy`` does.
    metrics : {"full", "accuracy"}
        ``"accuracy"`` keeps acc@5 / acc@15 only (fast).

    Returns
    -------
    dict
        ``{"sequences": [{"family", "name", "seed", "description", label: {metric: value}}],
        "families": {family: {label: {metric: {"mean", "std", "n"}}}},
        "summary": {label: {metric: {"mean", "std", "n"}}}, "paired": {label: {metric:
        {"mean", "std", "better", "worse", "n"}}}, "reference", "labels", "seeds_per_family",
        "threshold_px"}``; the spread is the standard deviation over sequences. ``paired``
        holds each label's per-sequence difference to the first label (the ``reference``,
        usually the defaults): its mean and spread, and on how many sequences it is better
        or worse.
    """
    from crowdsim.progress import progress_bar
    from tracker.runner import run_tracker

    runners = {label: _policy_runner(pol) for label, pol in (policies or {}).items()}
    labels = [*param_sets, *runners]
    if len(set(labels)) != len(labels):
        raise ValueError(f"held-out: labels must be distinct, got {labels}")
    rows: list[dict[str, Any]] = []
    skipped: list[str] = []
    episodes = progress_bar(
        heldout_episodes(objective, seeds, skipped),
        total=heldout_count(objective, seeds),
        desc="held-out",
        unit="seq",
        enabled=progress,
    )
    for family, seq, spec in episodes:
        row: dict[str, Any] = {
            "family": family,
            "name": getattr(seq, "name", family),
            "seed": getattr(spec, "seed", None),
            "description": getattr(spec, "description", "") or "",
        }
        for label, params in param_sets.items():
            run = run_tracker(objective.tracker, seq, params=params, metrics=metrics)
            row[label] = {k: float(run.report[k]) for k in METRICS if k in run.report}
        for label, make in runners.items():
            trk, ctl = make(seq)
            run = run_tracker(trk, ctl, metrics=metrics)
            row[label] = {k: float(run.report[k]) for k in METRICS if k in run.report}
        rows.append(row)
    families: dict[str, dict[str, Any]] = {}
    for fam in dict.fromkeys(r["family"] for r in rows):
        mine = [r for r in rows if r["family"] == fam]
        families[fam] = {
            label: {k: _stats([r[label][k] for r in mine]) for k in METRICS if k in mine[0][label]}
            for label in labels
        }
    summary = {
        label: {k: _stats([r[label][k] for r in rows]) for k in METRICS if k in rows[0][label]}
        for label in labels
    }
    ref = labels[0]
    paired = {}
    for label in labels[1:]:
        paired[label] = {}
        for k in summary[ref]:
            d = np.array([r[label][k] - r[ref][k] for r in rows])
            paired[label][k] = {
                "mean": float(d.mean()),
                "std": float(d.std()),
                "better": int((d > 0).sum()),
                "worse": int((d < 0).sum()),
                "n": len(d),
            }
    return {
        "labels": labels,
        "reference": ref,
        "paired": paired,
        "seeds_per_family": 1 if objective.folder else int(seeds),  # folders: once each
        "threshold_px": objective.threshold_px,
        "sequences": rows,
        "skipped_empty": skipped,
        "families": families,
        "summary": summary,
    }


def heldout_table(
    result: Mapping[str, Any], keys: tuple[str, ...] = ("acc@5", "acc@15", "hota")
) -> str:
    """Markdown: one row per family and label, the overall rows (mean +- std), then each
    label's paired difference to the reference (mean +- std over sequences, how many better)."""
    labels = result["labels"]
    keys = tuple(k for k in keys if k in result["summary"][labels[0]])
    head = "| family | n | " + " | ".join(["method", *keys]) + " |"
    lines = [head, "|" + "---|" * (3 + len(keys))]

    def cells(block: Mapping[str, Any]) -> str:
        return " | ".join(f"{block[k]['mean']:.1f} ± {block[k]['std']:.1f}" for k in keys)

    for fam, by_label in [*result["families"].items(), ("all", result["summary"])]:
        for label in labels:
            n = by_label[label][keys[0]]["n"]
            lines.append(f"| {fam} | {n} | {label} | {cells(by_label[label])} |")
    ref = result["reference"]
    for label, diff in result["paired"].items():
        d = [
            f"{c['mean']:+.1f} ± {c['std']:.1f} ({c['better']}/{c['n']} better)"
            for c in (diff[k] for k in keys)
        ]
        lines.append(f"| paired | {diff[keys[0]]['n']} | {label} − {ref} | " + " | ".join(d) + " |")
    return "\n".join(lines) + "\n"


def plot_heldout(
    result: Mapping[str, Any], path: Any, keys: tuple[str, ...] = ("acc@5", "acc@15")
) -> Any:
    """Per-family mean of each of ``keys`` the result holds (one panel each: the papers'
    two thresholds by default) for every label, with the spread as error bars, PNG."""
    from crowdsim.plotting import new_figure, save_figure

    labels = result["labels"]
    fams = [*result["families"], "all"]
    blocks = [*result["families"].values(), result["summary"]]
    keys = tuple(k for k in keys if k in result["summary"][labels[0]]) or ("acc@5",)
    width = 0.8 / max(len(labels), 1)
    panel = max(3.2, 0.9 * len(fams) + 1.6)
    fig, axes = new_figure(figsize=(panel * len(keys), 4.0), ncols=len(keys))
    axes = np.atleast_1d(axes)
    x = np.arange(len(fams))
    for ax, key in zip(axes, keys, strict=True):
        for j, label in enumerate(labels):
            mean = [b[label][key]["mean"] for b in blocks]
            std = [b[label][key]["std"] for b in blocks]
            off = (j - (len(labels) - 1) / 2) * width
            ax.bar(x + off, mean, width, yerr=std, capsize=2, label=label)
        ax.set_xticks(x, fams)
        ax.set_ylabel(f"{key} (%)")
        ax.set_title(key, fontsize=10)
        ax.set_ylim(0, 125)  # the legend's band above 100 %, clear of the bars
        ax.set_yticks(np.arange(0, 101, 20))
        ax.grid(axis="y", alpha=0.3)
    axes[-1].legend(loc="upper center", ncol=len(labels), fontsize=8)
    n = result["seeds_per_family"]
    seeds = f"{n} seed{'s' if n != 1 else ''} per family"
    fig.suptitle(f"held-out sequences, {seeds}; bars: mean, whiskers: std", fontsize=10)
    return save_figure(fig, path, dpi=110)


HELDOUT_FILES: tuple[str, ...] = ("heldout.json", "heldout.md", "heldout.png")
"""What :func:`write_heldout` writes: the record, then its table and its plot."""


def _is_heldout(doc: Any) -> bool:
    return isinstance(doc, dict) and "seeds_per_family" in doc and "families" in doc


def check_heldout_out(out: Any, flag: str = "--out") -> None:
    """Refuse (``ValueError`` naming ``flag`` and the file) a folder whose ``heldout.json``,
    ``heldout.md`` or ``heldout.png`` this program cannot prove it wrote (a user's own notes
    or plot), before any work; see :mod:`envs.outputs`."""
    from envs.outputs import check_outputs

    check_outputs(
        out, HELDOUT_FILES[0], HELDOUT_FILES[1:], _is_heldout, "crowdsim heldout", flag=flag
    )


def write_heldout(result: Mapping[str, Any], out: Any) -> dict[str, str]:
    """Write ``heldout.json``, ``heldout.md`` (:func:`heldout_table`) and ``heldout.png``
    (:func:`plot_heldout`) into ``out``, each atomically, the JSON listing the others'
    SHA-256 (so a rerun replaces them and nothing else: :func:`check_heldout_out`);
    ``{kind: path}``."""
    from envs.outputs import write_outputs

    paths = write_outputs(
        out,
        "heldout.json",
        result,
        {
            "heldout.md": lambda p: p.write_text(heldout_table(result)),
            "heldout.png": lambda p: plot_heldout(result, p),
        },
    )
    kinds = {
        "heldout": "heldout.json",
        "heldout_table": "heldout.md",
        "heldout_plot": "heldout.png",
    }
    return {kind: str(paths[name]) for kind, name in kinds.items()}
