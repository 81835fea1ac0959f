"""Tracking metrics (SPEC §7).

* The papers' metric: the percentage of ground-truth points whose tracked point of the same id
  lies within ``T`` pixels, for ``T = 0 .. 25`` (:func:`accuracy_curve`); tables at 5 and 15 px
  and one curve per method (:func:`plot_accuracy`).
* CLEAR MOT, IDF1 and HOTA from TrackEval's metric classes (:func:`trackeval_metrics`), fed
  with the point-distance similarity ``max(0, 1 - d / T_sim)`` between every ground-truth and
  tracked point of a frame. TrackEval matches at similarity >= 0.5 for CLEAR and IDF1, i.e.
  within ``T_sim / 2`` px; HOTA averages over its thresholds ``alpha = 0.05 .. 0.95``.

Which metrics need the track ids to be the ground-truth ids
    MOTA, IDF1 and HOTA match tracks to ground truth themselves: they take **any** track ids
    (a tracking-by-detection tracker creates its own). Only the papers' acc@T compares "the
    tracked point of the same id", so it needs a correspondence, chosen by ``id_mapping``:

    * ``"same"``: the track ids are ground-truth ids (the point trackers: they are given the
      people's ids at birth);
    * ``"majority"``: each track stands for the ground-truth person it lies within
      :data:`SIMILARITY_SCALE` px of (nearest one) in most of its frames (:func:`map_track_ids`;
      :func:`evaluate`'s ``similarity_scale``, TrackEval's ``T_sim``, never moves it);
      a person followed by several tracks in turn takes, in each frame, the position of the
      track with most votes that is present (:func:`mapped_positions`);
    * ``"auto"`` (:func:`evaluate`'s default): ``"same"`` when the track ids are the ground
      truth's, else ``"majority"`` (:func:`resolve_id_mapping`). When no track id is a
      ground-truth id, they are not; when some or all are, the evidence decides (a head
      detector's 1..N and an annotator's 1..N share their numbers by chance):
      the ids are the ground truth's when more than :data:`ID_AGREEMENT` of the known-id
      tracks that start within :data:`SIMILARITY_SCALE` px of someone start within that
      distance of the person *of their id* (a point tracker's tracks are born on their
      person, however often they swap later; a tracker with its own ids 0, 1, 2, ...
      starts on the person of the same number by chance only). Under
      ``"same"`` a track id unknown to the ground truth (a stray row, a negative id) is
      scored as unmatched -- it never turns the rest of the result to majority mapping --
      and :func:`evaluate` counts such ids in ``unknown_ids``. Trackers whose own ids may
      collide with ground-truth ids declare ``id_mapping = "majority"`` and the runner passes
      it.

Tracks are ``ids (N,)`` and ``positions (T, N, 2)`` pixels, NaN where absent; frames are
aligned by index (frame 0 = the first frame of the sequence).
"""

from __future__ import annotations

import os
from typing import Any

import numpy as np

from crowdsim.checks import MEMORY_LIMIT_BYTES, checked_ids, format_bytes, require_choice
from crowdsim.plotting import new_figure, save_figure

THRESHOLDS: np.ndarray = np.arange(26)
"""Pixel thresholds ``T = 0 .. 25`` of the papers' accuracy curve."""
SIMILARITY_SCALE: float = 15.0
"""``T_sim`` (px) of the point similarity ``max(0, 1 - d / T_sim)`` fed to TrackEval."""


def _align(gt_ids, gt_points, tr_ids, tr_points, strict: bool):
    gt_ids = checked_ids("gt_ids", gt_ids)
    tr_ids = checked_ids("tr_ids", tr_ids)
    gt_points = np.asarray(gt_points, dtype=np.float64)
    tr_points = np.asarray(tr_points, dtype=np.float64)
    if gt_points.ndim != 3 or gt_points.shape[1:] != (len(gt_ids), 2):
        raise ValueError(
            f"ground truth must have shape (T, {len(gt_ids)}, 2), got {gt_points.shape}"
        )
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
        raise ValueError(
            f"the tracks hold {len(unknown)} ids unknown to the ground truth "
            f"(e.g. {unknown[:5].tolist()})"
        )
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


ID_MAPPINGS = ("auto", "same", "majority")
"""Ways to relate track ids to ground-truth ids for acc@T (module docstring)."""
ID_AGREEMENT: float = 0.1
"""Under ``"auto"`` with track ids known to the ground truth: the ids count as the ground
truth's when, of the known-id tracks that start near someone, more than this share start near
the person of their own id (:func:`resolve_id_mapping`). Measured on the first 80 frames of
ucf9 seq5 / seq9 (``crowdsim`` 2026-11-27): NCC and mean-shift 1.0 / 1.0 (their tracks are born
on their people); ByteTrack, 239 of whose 243 own ids (0, 1, 2, ...) are also ids of seq5's
people, 0.038 / 0.018: chance, about one in the number of people. Judged on every frame
instead of the first, as before, mean-shift's share was 0.19 / 0.52 and NCC's 0.95 / 0.95:
a weaker point tracker, or one that swaps early, came close to the line and past it."""


def map_track_ids(
    gt_ids, gt_points, tr_ids, tr_points, radius: float = SIMILARITY_SCALE
) -> tuple[np.ndarray, np.ndarray]:
    """Majority vote: the ground-truth id each track stands for.

    In every frame each tracked point votes for the nearest ground-truth point within
    ``radius`` px; a track takes the id with most votes (ties: the earlier gt column).

    Returns
    -------
    gt_of_track : (N_tr,) int64
        Ground-truth id per track, ``-1`` for a track never within ``radius`` of anyone.
    votes : (N_tr,) int64
        Frames supporting that id.

    >>> gt = np.array([[[0.0, 0.0], [50.0, 0.0]]] * 3)
    >>> ids, votes = map_track_ids([7, 8], gt, [0, 1, 2], gt[:, [1, 0, 0]] + [0.0, 200.0])
    >>> ids.tolist(), votes.tolist()
    ([-1, -1, -1], [0, 0, 0])
    >>> map_track_ids([7, 8], gt, [0, 1], gt[:, [1, 0]] + 2.0)[0].tolist()
    [8, 7]
    """
    from scipy.spatial import cKDTree

    gt_ids, gt_points, tr_ids, tr_points = _align(gt_ids, gt_points, tr_ids, tr_points, False)
    if not radius > 0:
        raise ValueError(f"radius must be > 0 px, got {radius!r}")
    n_gt, n_tr = len(gt_ids), len(tr_ids)
    gt_ok = np.isfinite(gt_points).all(-1)
    tr_ok = np.isfinite(tr_points).all(-1)
    tr_col, gt_col = [np.zeros(0, np.int64)], [np.zeros(0, np.int64)]
    for t in np.flatnonzero(gt_ok.any(1) & tr_ok.any(1)):
        g = np.flatnonzero(gt_ok[t])
        r = np.flatnonzero(tr_ok[t])
        d, j = cKDTree(gt_points[t, g]).query(tr_points[t, r], distance_upper_bound=radius)
        hit = np.isfinite(d)
        tr_col.append(r[hit])
        gt_col.append(g[j[hit]])
    best = np.full(n_tr, -1, np.int64)
    votes = np.zeros(n_tr, np.int64)
    key = np.concatenate(tr_col) * max(n_gt, 1) + np.concatenate(gt_col)
    if key.size:
        uniq, counts = np.unique(key, return_counts=True)
        tr_u, gt_u = uniq // n_gt, uniq % n_gt
        order = np.lexsort((gt_u, -counts, tr_u))
        tr_s = tr_u[order]
        first = np.r_[True, tr_s[1:] != tr_s[:-1]]
        best[tr_s[first]] = gt_ids[gt_u[order][first]]
        votes[tr_s[first]] = counts[order][first]
    return best, votes


def mapped_positions(
    gt_ids, gt_points, tr_ids, tr_points, radius: float = SIMILARITY_SCALE
) -> np.ndarray:
    """``(T, N_gt, 2)`` tracked position of each ground-truth person under the majority map.

    In each frame, a person's position is that of the present track mapped to them
    (:func:`map_track_ids`) with most votes; NaN where none is present.
    """
    gt_ids, gt_points, tr_ids, tr_points = _align(gt_ids, gt_points, tr_ids, tr_points, False)
    best, votes = map_track_ids(gt_ids, gt_points, tr_ids, tr_points, radius)
    out = np.full(gt_points.shape, np.nan)
    k = np.flatnonzero(best >= 0)
    if k.size == 0:
        return out
    g = np.searchsorted(np.sort(gt_ids), best[k])
    g = np.argsort(gt_ids)[g]  # gt column of each mapped track
    order = np.lexsort((k, -votes[k], g))  # by person, then priority
    k, g = k[order], g[order]
    starts = np.flatnonzero(np.r_[True, g[1:] != g[:-1]])
    present = np.isfinite(tr_points[:, k]).all(-1)
    rank = np.arange(len(k), 0, -1)  # unique and larger for higher priority
    top = np.maximum.reduceat(present * rank, starts, axis=1)  # (T, persons)
    pick = k[len(k) - np.maximum(top, 1)]
    pts = tr_points[np.arange(len(tr_points))[:, None], pick]
    out[:, g[starts]] = np.where((top > 0)[..., None], pts, np.nan)
    return out


def _real(values: Any) -> bool:
    return np.asarray(values).dtype.kind in "iuf"


def accuracy_curve(
    gt_ids,
    gt_points,
    tr_ids,
    tr_points,
    thresholds=THRESHOLDS,
    strict: bool = False,
    id_mapping: str = "same",
    radius: float = SIMILARITY_SCALE,
) -> np.ndarray:
    """The papers' metric: % of ground-truth points tracked within ``T`` px, per threshold.

    Returns ``(len(thresholds),)`` float64 percentages (0 when there is no gt point).
    ``id_mapping`` (``"same"``, ``"majority"``, ``"auto"``; module docstring) relates track
    ids to ground-truth ids; ``strict`` refuses unknown ids under ``"same"``; ``radius`` is the
    majority-vote radius (px).

    >>> gt = np.array([[[0.0, 0.0], [10.0, 0.0]]])
    >>> tr = np.array([[[3.0, 4.0], [10.0, 0.0]]])
    >>> accuracy_curve([1, 2], gt, [1, 2], tr, thresholds=[0, 5]).tolist()
    [50.0, 100.0]
    """
    gt_ids, tr_ids = checked_ids("gt_ids", gt_ids), checked_ids("tr_ids", tr_ids)
    th = np.asarray(thresholds, dtype=np.float64) if _real(thresholds) else None
    if th is None or th.ndim != 1 or not np.isfinite(th).all():
        raise ValueError(f"thresholds must be a 1-D array of finite px, got {thresholds!r}")
    mode = resolve_id_mapping(gt_ids, tr_ids, id_mapping, gt_points, tr_points, radius)
    if mode == "majority":
        tr_points = mapped_positions(gt_ids, gt_points, tr_ids, tr_points, radius)
        tr_ids = gt_ids
    # "auto" decided on the ids themselves: unknown ones are unmatched, never refused
    err = point_errors(gt_ids, gt_points, tr_ids, tr_points, strict and id_mapping == "same")
    e = err[~np.isnan(err)]
    if e.size == 0:
        return np.zeros(len(th))
    e = np.sort(e)
    return 100.0 * np.searchsorted(e, th, side="right") / e.size


def trackeval_data(
    gt_ids, gt_points, tr_ids, tr_points, similarity_scale: float = SIMILARITY_SCALE
) -> dict[str, Any]:
    """TrackEval's per-sequence ``data`` dict with point similarities ``max(0, 1 - d/T)``;
    refused with the estimate when its tables would pass the memory limit
    (:func:`trackeval_bytes`)."""
    gt_ids, gt_points, tr_ids, tr_points = _align(gt_ids, gt_points, tr_ids, tr_points, False)
    if not similarity_scale > 0:
        raise ValueError(f"similarity_scale must be > 0 px, got {similarity_scale!r}")
    gt_present = np.isfinite(gt_points).all(-1)
    tr_present = np.isfinite(tr_points).all(-1)
    need = _tables_bytes(gt_present, tr_present)  # sized before any table is built
    if need > MEMORY_LIMIT_BYTES:
        raise ValueError(
            f"MOTA, IDF1 and HOTA of {len(gt_points)} frames with {len(gt_ids)} people and "
            f"{len(tr_ids)} tracks need about {format_bytes(need)} of memory in TrackEval, "
            f"more than the {format_bytes(MEMORY_LIMIT_BYTES)} limit; score the papers' acc@T "
            "alone (crowdsim evaluate --metrics accuracy), or fewer frames"
        )
    gt_used = np.flatnonzero(gt_present.any(0))
    tr_used = np.flatnonzero(tr_present.any(0))
    gt_map = np.full(len(gt_ids), -1, np.int64)
    gt_map[gt_used] = np.arange(len(gt_used))
    tr_map = np.full(len(tr_ids), -1, np.int64)
    tr_map[tr_used] = np.arange(len(tr_used))
    data: dict[str, Any] = {
        "gt_ids": [],
        "tracker_ids": [],
        "similarity_scores": [],
        "num_timesteps": gt_points.shape[0],
    }
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


def trackeval_bytes(gt_points: np.ndarray, tr_points: np.ndarray) -> int:
    """Bytes TrackEval's CLEAR, Identity and HOTA hold at their peak on ``(T, N_gt, 2)`` and
    ``(T, N_tr, 2)`` points: the dense float64 similarity table of every frame
    (:func:`trackeval_data`) and six frames' temporaries, HOTA's 21 and Identity's ids x ids
    tables (``G R``; ``(G + R)^2`` three times for its assignment)."""
    gt = np.isfinite(np.asarray(gt_points, np.float64)).all(-1)
    tr = np.isfinite(np.asarray(tr_points, np.float64)).all(-1)
    return _tables_bytes(gt, tr)


def _tables_bytes(gt: np.ndarray, tr: np.ndarray) -> int:
    """:func:`trackeval_bytes` of the ``(T, N)`` presence masks."""
    pairs = gt.sum(1).astype(np.float64) * tr.sum(1)
    g, r = float(gt.any(0).sum()), float(tr.any(0).sum())
    peak = pairs.max(initial=0.0)
    return int(8 * (pairs.sum() + 6 * peak + 22 * g * r + 3 * (g + r) ** 2))


def trackeval_metrics(
    gt_ids, gt_points, tr_ids, tr_points, similarity_scale: float = SIMILARITY_SCALE
) -> dict[str, float]:
    """CLEAR MOT, IDF1 and HOTA from TrackEval (percentages; IDSW etc. as counts).

    TrackEval keeps a dense similarity table per frame and ids x ids tables: a request whose
    :func:`trackeval_bytes` exceeds :data:`crowdsim.checks.MEMORY_LIMIT_BYTES` (about 3,400
    people in each of 100 frames) is refused with the estimate before anything is built;
    :func:`accuracy_curve` (the papers' acc@T) needs no such tables."""
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


def resolve_id_mapping(
    gt_ids, tr_ids, id_mapping: str, gt_points=None, tr_points=None, radius=SIMILARITY_SCALE
) -> str:
    """``"same"`` or ``"majority"``: ``id_mapping`` with ``"auto"`` decided (module docstring).

    With track ids known to the ground truth, ``"auto"`` looks at the points (``(T, N_gt,
    2)`` and ``(T, N_tr, 2)``): the ids are the ground truth's when more than
    :data:`ID_AGREEMENT` of the known-id tracks whose first point lies within ``radius`` px of
    someone have it within ``radius`` px of the person of their own id. The first point
    alone: a point tracker that swaps people early has a track on another person in most
    of its frames, and judged on every frame it was scored by majority vote as if it had
    never swapped (90 % instead of 10 % on two people swapped from the second frame on).
    Without the points, ids that are all known count as the ground truth's; some unknown
    ones need the points.

    >>> resolve_id_mapping([1, 2], [2], "auto"), resolve_id_mapping([1, 2], [3], "auto")
    ('same', 'majority')
    >>> gt = np.array([[[0.0, 0.0], [50.0, 0.0]]] * 3)
    >>> resolve_id_mapping([1, 2], [2, 1], "auto", gt, gt)  # known numbers, other people
    'majority'
    >>> resolve_id_mapping([1, 2], [1, 2, -1], "auto", gt, gt[:, [0, 1, 1]])  # a stray id
    'same'
    >>> resolve_id_mapping([1, 2], [0, 1], "auto", gt, gt)  # own ids 0, 1: not the people's
    'majority'
    >>> resolve_id_mapping([1, 2], [1, 2], "auto", gt, np.concatenate([gt[:1], gt[1:, ::-1]]))
    'same'
    """
    require_choice("", "id_mapping", id_mapping, ID_MAPPINGS)
    gt_ids, tr_ids = checked_ids("gt_ids", gt_ids), checked_ids("tr_ids", tr_ids)
    if id_mapping != "auto":
        return id_mapping
    known = np.isin(tr_ids, gt_ids)
    if not len(tr_ids):  # no track: nothing to map
        return "same"
    if not known.any():
        return "majority"
    if gt_points is None or tr_points is None:
        if known.all():
            return "same"
        raise ValueError('id_mapping="auto" with some unknown track ids needs the points')
    gt_ids, gt_points, tr_ids, tr_points = _align(gt_ids, gt_points, tr_ids, tr_points, False)
    start = _first_points(tr_points[:, known])
    own = point_errors(gt_ids, gt_points, tr_ids[known], start) <= radius
    near = _near_anyone(gt_points, start, radius)
    if near == 0:  # no evidence either way: known ids are taken at their word
        return "same" if known.all() else "majority"
    return "same" if int(own.sum()) > ID_AGREEMENT * near else "majority"


def _first_points(tr_points: np.ndarray) -> np.ndarray:
    """``(T, N, 2)`` tracks with each track's first point alone kept (NaN elsewhere)."""
    present = np.isfinite(tr_points).all(-1)
    cols = np.flatnonzero(present.any(0))
    rows = np.argmax(present[:, cols], axis=0)
    first = np.full_like(tr_points, np.nan)
    first[rows, cols] = tr_points[rows, cols]
    return first


def _near_anyone(gt_points: np.ndarray, tr_points: np.ndarray, radius: float) -> int:
    """Number of tracked points ``(T, N_tr, 2)`` within ``radius`` px of a ground-truth point
    ``(T, N_gt, 2)`` of their frame."""
    from scipy.spatial import cKDTree

    gt_ok = np.isfinite(gt_points).all(-1)
    tr_ok = np.isfinite(tr_points).all(-1)
    n = 0
    for t in np.flatnonzero(gt_ok.any(1) & tr_ok.any(1)):
        d, _ = cKDTree(gt_points[t, gt_ok[t]]).query(tr_points[t, tr_ok[t]])
        n += int((d <= radius).sum())
    return n


def evaluate(
    gt_ids,
    gt_points,
    tr_ids,
    tr_points,
    similarity_scale: float = SIMILARITY_SCALE,
    strict: bool = True,
    id_mapping: str = "auto",
    trackeval: bool = True,
) -> dict[str, Any]:
    """Every metric of one sequence as a JSON-ready dict.

    Keys: ``acc@5``, ``acc@15`` (the papers' metric, %), ``mota``, ``motp``, ``idf1``, ``hota``,
    ``deta``, ``assa`` (%), ``idsw``, ``mt``, ``ml``, ``frag`` (counts), ``curve`` (list of
    ``{"T": px, "acc": %}`` for ``T = 0..25``), ``gt_points``, ``gt_ids``, ``similarity_px``,
    ``id_mapping`` (how acc@T related track ids to ground-truth ids: ``"same"`` or
    ``"majority"``), ``unknown_ids`` (under ``"same"``: how many track ids are unknown to the
    ground truth, their points scored as unmatched; 0 under ``"majority"``).

    MOTA, IDF1 and HOTA are computed for any track ids. ``id_mapping`` (default ``"auto"``)
    only concerns acc@T (module docstring); ``strict`` refuses track ids unknown to the ground
    truth when ``id_mapping="same"`` is asked for (``"auto"`` scores them as unmatched).
    ``trackeval=False`` leaves out TrackEval's keys (``mota`` ... ``frag``): acc@T alone, for
    crowds too large for its tables (:func:`trackeval_metrics`).
    """
    gt_ids, tr_ids = checked_ids("gt_ids", gt_ids), checked_ids("tr_ids", tr_ids)
    # the id correspondence of acc@T (the papers' metric) never moves with TrackEval's T_sim
    mode = resolve_id_mapping(gt_ids, tr_ids, id_mapping, gt_points, tr_points)
    if id_mapping == "same" and strict:
        _align(gt_ids, gt_points, tr_ids, tr_points, True)  # unknown ids refused
    curve = accuracy_curve(gt_ids, gt_points, tr_ids, tr_points, THRESHOLDS, False, mode)
    out: dict[str, Any] = {"acc@5": float(curve[5]), "acc@15": float(curve[15])}
    if trackeval:
        out.update(trackeval_metrics(gt_ids, gt_points, tr_ids, tr_points, similarity_scale))
    out["curve"] = [{"T": int(t), "acc": float(a)} for t, a in zip(THRESHOLDS, curve, strict=True)]
    gp = np.asarray(gt_points)
    out["gt_points"] = int(np.isfinite(gp).all(-1).sum())
    out["gt_ids"] = int(np.isfinite(gp).all(-1).any(0).sum())  # people in the frames scored
    out["similarity_px"] = float(similarity_scale)
    out["id_mapping"] = mode
    unknown = ~np.isin(tr_ids, gt_ids)
    out["unknown_ids"] = int(unknown.sum()) if mode == "same" else 0
    return out


def format_table(results: dict[str, dict[str, Any]]) -> str:
    """Plain-text table, one row per method: acc@5, acc@15, MOTA, IDF1, HOTA, IDSW (``-``
    where a report has no TrackEval metrics)."""
    head = f"{'method':<12}{'acc@5':>8}{'acc@15':>8}{'MOTA':>8}{'IDF1':>8}{'HOTA':>8}{'IDSW':>7}"
    lines = [head, "-" * len(head)]
    for name, r in results.items():
        # a space before each figure: a MOTA of -1000 % or less stays apart from acc@15
        row = f"{name:<12} {r['acc@5']:>6.1f}% {r['acc@15']:>6.1f}%"
        if "mota" in r:
            row += f" {r['mota']:>6.1f}% {r['idf1']:>6.1f}% {r['hota']:>6.1f}% {r['idsw']:>6d}"
        else:
            row += f"{'-':>8}{'-':>8}{'-':>8}{'-':>7}"
        lines.append(row)
    return "\n".join(lines)


def plot_accuracy(
    curves: dict[str, np.ndarray], path: str | os.PathLike[str], title: str = ""
) -> None:
    """Accuracy vs pixel threshold, one line per method (the papers' Fig. 9-10), as PNG.

    Up to four methods share the plot with their legend; more get the legend beside it."""
    beside = len(curves) > 4
    fig, ax = new_figure(figsize=(7.2 if beside else 5, 3.6), dpi=120)
    styles = ("-", "--", ":", "-.")  # past the colour cycle's 10 colours, another line style
    for k, (name, curve) in enumerate(curves.items()):
        curve = np.asarray(curve, dtype=np.float64)
        ax.plot(
            THRESHOLDS[: len(curve)],
            curve,
            styles[(k // 10) % len(styles)],
            marker="os^D"[(k // 10) % 4],
            markersize=3,
            label=name,
        )
    ax.set_xlabel("pixel threshold T (px)")
    ax.set_ylabel("tracking accuracy (%)")
    # a little room past 0-25 px and 0-100 %: a curve at 100 % (or its first and last
    # markers) would otherwise lie on the axes' frame, half hidden and unreadable
    ax.set_xlim(-0.5, THRESHOLDS[-1] + 0.5)
    ax.set_ylim(-1.5, 101.5)
    ax.grid(alpha=0.3)
    if beside:
        ax.legend(loc="upper left", bbox_to_anchor=(1.02, 1.0), fontsize="small")
    else:
        ax.legend(loc="lower right")
    if title:
        ax.set_title(title)
    save_figure(fig, path, dpi=120)
