"""Tracking metrics (SPEC §7).

* The papers' metric: the percentage of ground-truth points whose tracked point of the same id
  lies within ``T`` pixels, for ``T = 0 .. 25`` (:func:`accuracy_curve`); tables at 5 and 15 px
  and one curve per method (:func:`plot_accuracy`).
* CLEAR MOT, IDF1 and HOTA from TrackEval's metric classes (:func:`trackeval_metrics`), fed
  with the point-distance similarity ``max(0, 1 - d / T_sim)`` between every ground-truth and
  tracked point of a frame. TrackEval matches at similarity >= 0.5 for CLEAR and IDF1, i.e.
  within ``T_sim / 2`` px; HOTA averages over its thresholds ``alpha = 0.05 .. 0.95``.

Tracks are ``ids (N,)`` and ``positions (T, N, 2)`` pixels, NaN where absent; frames are
aligned by index (frame 0 = the first frame of the sequence).
"""

from __future__ import annotations

import os
from typing import Any

import numpy as np

from crowdsim.plotting import save_figure

THRESHOLDS: np.ndarray = np.arange(26)
"""Pixel thresholds ``T = 0 .. 25`` of the papers' accuracy curve."""
SIMILARITY_SCALE: float = 15.0
"""``T_sim`` (px) of the point similarity ``max(0, 1 - d / T_sim)`` fed to TrackEval."""


def _align(gt_ids, gt_points, tr_ids, tr_points, strict: bool):
    gt_ids = np.asarray(gt_ids, dtype=np.int64)
    tr_ids = np.asarray(tr_ids, dtype=np.int64)
    gt_points = np.asarray(gt_points, dtype=np.float64)
    tr_points = np.asarray(tr_points, dtype=np.float64)
    if gt_points.ndim != 3 or gt_points.shape[1:] != (len(gt_ids), 2):
        raise ValueError(f"ground truth must have shape (T, {len(gt_ids)}, 2), got "
                         f"{gt_points.shape}")
    if tr_points.ndim != 3 or tr_points.shape[1:] != (len(tr_ids), 2):
        raise ValueError(f"tracks must have shape (T, {len(tr_ids)}, 2), got {tr_points.shape}")
    t = gt_points.shape[0]
    if tr_points.shape[0] > t:
        raise ValueError(f"tracks have {tr_points.shape[0]} frames but the ground truth only {t}")
    if tr_points.shape[0] < t:
        pad = np.full((t - tr_points.shape[0], len(tr_ids), 2), np.nan)
        tr_points = np.concatenate([tr_points, pad])
    unknown = np.setdiff1d(tr_ids, gt_ids)
    if strict and len(unknown):
        raise ValueError(f"the tracks hold {len(unknown)} ids unknown to the ground truth "
                         f"(e.g. {unknown[:5].tolist()})")
    return gt_ids, gt_points, tr_ids, tr_points


def point_errors(gt_ids, gt_points, tr_ids, tr_points, strict: bool = False) -> np.ndarray:
    """``(T, N_gt)`` distance (px) from each gt point to the tracked point of the same id.

    NaN where the ground-truth point is absent, ``inf`` where it is present but not tracked.
    """
    gt_ids, gt_points, tr_ids, tr_points = _align(gt_ids, gt_points, tr_ids, tr_points, strict)
    err = np.full(gt_points.shape[:2], np.inf)
    if len(tr_ids):
        order = np.argsort(tr_ids)
        sorted_ids = tr_ids[order]
        pos = np.minimum(np.searchsorted(sorted_ids, gt_ids), len(tr_ids) - 1)
        cols = np.flatnonzero(sorted_ids[pos] == gt_ids)
        tr = tr_points[:, order[pos[cols]]]
        d = np.sqrt(((gt_points[:, cols] - tr) ** 2).sum(-1))
        err[:, cols] = np.where(np.isfinite(d), d, np.inf)
    err[~np.isfinite(gt_points).all(-1)] = np.nan
    return err


def accuracy_curve(gt_ids, gt_points, tr_ids, tr_points, thresholds=THRESHOLDS,
                   strict: bool = False) -> np.ndarray:
    """The papers' metric: % of ground-truth points tracked within ``T`` px, per threshold.

    Returns ``(len(thresholds),)`` float64 percentages (0 when there is no gt point).

    >>> gt = np.array([[[0.0, 0.0], [10.0, 0.0]]])
    >>> tr = np.array([[[3.0, 4.0], [10.0, 0.0]]])
    >>> accuracy_curve([1, 2], gt, [1, 2], tr, thresholds=[0, 5]).tolist()
    [50.0, 100.0]
    """
    err = point_errors(gt_ids, gt_points, tr_ids, tr_points, strict)
    e = err[~np.isnan(err)]
    th = np.asarray(thresholds, dtype=np.float64)
    if e.size == 0:
        return np.zeros(len(th))
    e = np.sort(e)
    return 100.0 * np.searchsorted(e, th, side="right") / e.size


def trackeval_data(gt_ids, gt_points, tr_ids, tr_points,
                   similarity_scale: float = SIMILARITY_SCALE) -> dict[str, Any]:
    """TrackEval's per-sequence ``data`` dict with point similarities ``max(0, 1 - d/T)``."""
    gt_ids, gt_points, tr_ids, tr_points = _align(gt_ids, gt_points, tr_ids, tr_points, False)
    if not similarity_scale > 0:
        raise ValueError(f"similarity_scale must be > 0 px, got {similarity_scale!r}")
    gt_present = np.isfinite(gt_points).all(-1)
    tr_present = np.isfinite(tr_points).all(-1)
    gt_used = np.flatnonzero(gt_present.any(0))
    tr_used = np.flatnonzero(tr_present.any(0))
    gt_map = np.full(len(gt_ids), -1, np.int64)
    gt_map[gt_used] = np.arange(len(gt_used))
    tr_map = np.full(len(tr_ids), -1, np.int64)
    tr_map[tr_used] = np.arange(len(tr_used))
    data: dict[str, Any] = {"gt_ids": [], "tracker_ids": [], "similarity_scores": [],
                            "num_timesteps": gt_points.shape[0]}
    for t in range(gt_points.shape[0]):
        g = np.flatnonzero(gt_present[t])
        r = np.flatnonzero(tr_present[t])
        d = np.sqrt(((gt_points[t, g][:, None] - tr_points[t, r][None]) ** 2).sum(-1))
        data["gt_ids"].append(gt_map[g])
        data["tracker_ids"].append(tr_map[r])
        data["similarity_scores"].append(np.maximum(0.0, 1.0 - d / similarity_scale))
    data["num_gt_ids"] = len(gt_used)
    data["num_tracker_ids"] = len(tr_used)
    data["num_gt_dets"] = int(gt_present.sum())
    data["num_tracker_dets"] = int(tr_present.sum())
    return data


def trackeval_metrics(gt_ids, gt_points, tr_ids, tr_points,
                      similarity_scale: float = SIMILARITY_SCALE) -> dict[str, float]:
    """CLEAR MOT, IDF1 and HOTA from TrackEval (percentages; IDSW etc. as counts)."""
    from trackeval.metrics import CLEAR, HOTA, Identity

    data = trackeval_data(gt_ids, gt_points, tr_ids, tr_points, similarity_scale)
    quiet = {"PRINT_CONFIG": False}
    clear = CLEAR(quiet).eval_sequence(data)
    ident = Identity(quiet).eval_sequence(data)
    hota = HOTA().eval_sequence(data)
    return {
        "mota": 100.0 * float(clear["MOTA"]),
        "motp": 100.0 * float(clear["MOTP"]),
        "idf1": 100.0 * float(ident["IDF1"]),
        "hota": 100.0 * float(np.mean(hota["HOTA"])),
        "deta": 100.0 * float(np.mean(hota["DetA"])),
        "assa": 100.0 * float(np.mean(hota["AssA"])),
        "idsw": int(clear["IDSW"]),
        "mt": int(clear["MT"]),
        "ml": int(clear["ML"]),
        "frag": int(clear["Frag"]),
    }


def evaluate(gt_ids, gt_points, tr_ids, tr_points, similarity_scale: float = SIMILARITY_SCALE,
             strict: bool = True) -> dict[str, Any]:
    """Every metric of one sequence as a JSON-ready dict.

    Keys: ``acc@5``, ``acc@15`` (the papers' metric, %), ``mota``, ``motp``, ``idf1``, ``hota``,
    ``deta``, ``assa`` (%), ``idsw``, ``mt``, ``ml``, ``frag`` (counts), ``curve`` (list of
    ``{"T": px, "acc": %}`` for ``T = 0..25``), ``gt_points``, ``gt_ids``, ``similarity_px``.
    """
    curve = accuracy_curve(gt_ids, gt_points, tr_ids, tr_points, THRESHOLDS, strict)
    out: dict[str, Any] = {"acc@5": float(curve[5]), "acc@15": float(curve[15])}
    out.update(trackeval_metrics(gt_ids, gt_points, tr_ids, tr_points, similarity_scale))
    out["curve"] = [{"T": int(t), "acc": float(a)} for t, a in zip(THRESHOLDS, curve,
                                                                   strict=True)]
    gp = np.asarray(gt_points)
    out["gt_points"] = int(np.isfinite(gp).all(-1).sum())
    out["gt_ids"] = int(len(gt_ids))
    out["similarity_px"] = float(similarity_scale)
    return out


def format_table(results: dict[str, dict[str, Any]]) -> str:
    """Plain-text table, one row per method: acc@5, acc@15, MOTA, IDF1, HOTA, IDSW."""
    head = f"{'method':<12}{'acc@5':>8}{'acc@15':>8}{'MOTA':>8}{'IDF1':>8}{'HOTA':>8}{'IDSW':>7}"
    lines = [head, "-" * len(head)]
    for name, r in results.items():
        lines.append(f"{name:<12}{r['acc@5']:>7.1f}%{r['acc@15']:>7.1f}%{r['mota']:>7.1f}%"
                     f"{r['idf1']:>7.1f}%{r['hota']:>7.1f}%{r['idsw']:>7d}")
    return "\n".join(lines)


def plot_accuracy(curves: dict[str, np.ndarray], path: str | os.PathLike[str],
                  title: str = "") -> None:
    """Accuracy vs pixel threshold, one line per method (the papers' Fig. 9-10), as PNG."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(5, 3.6), dpi=120)
    for name, curve in curves.items():
        curve = np.asarray(curve, dtype=np.float64)
        ax.plot(THRESHOLDS[:len(curve)], curve, marker="o", markersize=3, label=name)
    ax.set_xlabel("pixel threshold T (px)")
    ax.set_ylabel("tracking accuracy (%)")
    ax.set_xlim(0, THRESHOLDS[-1])
    ax.set_ylim(0, 100)
    ax.grid(alpha=0.3)
    ax.legend(loc="lower right")
    if title:
        ax.set_title(title)
    save_figure(fig, path, dpi=120)
