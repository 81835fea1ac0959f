"""Test material shipped with the tracker library: scenes, QPs and the tracker contract check.

* :func:`make_scene` -- tiny hand-built scenes with exact ground truth;
* :func:`synthetic_frame_qp` -- relaxed QPs shaped like a BQP tracking frame (solver tests and
  ``crowdsim bench solver``);
* :func:`check_tracker_contract` -- the tracker contract, for any tracker: a conformance check
  that outside tracker authors run on their own implementation (as PettingZoo's
  ``parallel_api_test``), and that ``tests/tracker/test_tracker_contract.py`` runs over every
  registered tracker; :func:`check_set_params` is its ``set_params`` part.

Scenes:

Coloured square "heads" of ``size`` px move at integer velocities over a seeded random
texture; positions are integer pixels, so a correct tracker recovers them exactly.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, fields, replace
from typing import Any

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import minimum_spanning_tree
from scipy.spatial import cKDTree

from tracker.bqp.qp import BlockQP

PALETTE = np.array(
    [
        [255, 40, 40],
        [40, 220, 255],
        [40, 40, 230],
        [40, 230, 40],
        [230, 40, 230],
        [240, 240, 40],
        [200, 200, 200],
        [20, 120, 250],
    ],
    dtype=np.uint8,
)


@dataclass
class Scene:
    frames: list[np.ndarray]
    ids: np.ndarray
    points: np.ndarray  # (T, N, 2) float, NaN where absent
    template_size: int


def make_scene(
    starts,
    velocities,
    n_frames: int = 12,
    shape=(96, 128),
    size: int = 8,
    seed: int = 0,
    colours=None,
    birth_frames=None,
    death_frames=None,
) -> Scene:
    """Two-tone blobs of ``size - 2`` px (dark 2x2 centre) at ``start + t * velocity`` (px).

    Target ``i`` is drawn from frame ``birth_frames[i]`` (default 0) up to, not including,
    frame ``death_frames[i]`` (default: never ends): a person who vanishes inside the view.
    """
    rng = np.random.default_rng(seed)
    starts = np.asarray(starts, dtype=np.int64).reshape(-1, 2)
    vel = np.asarray(velocities, dtype=np.int64).reshape(-1, 2)
    n = len(starts)
    h, w = shape
    bg = rng.integers(70, 130, (h, w, 3)).astype(np.uint8)
    cols = PALETTE[np.arange(n) % len(PALETTE)] if colours is None else np.asarray(colours)
    birth = np.zeros(n, np.int64) if birth_frames is None else np.asarray(birth_frames)
    death = np.full(n, n_frames) if death_frames is None else np.asarray(death_frames)
    pts = np.full((n_frames, n, 2), np.nan)
    frames = []
    half = (size - 2) // 2
    for t in range(n_frames):
        f = bg.copy()
        for i in range(n):
            if t < birth[i] or t >= death[i]:
                continue
            x, y = starts[i] + (t - birth[i]) * vel[i]
            if not (0 <= x < w and 0 <= y < h):
                continue
            pts[t, i] = (x, y)
            f[max(0, y - half) : y + half + 1, max(0, x - half) : x + half + 1] = cols[i]
            # a dark "head" in the middle so that no template is flat (NCC needs variance)
            f[max(0, y - 1) : y + 1, max(0, x - 1) : x + 1] = cols[i] // 4
        frames.append(f)
    return Scene(frames, np.arange(1, n + 1), pts, size)


@dataclass(frozen=True)
class FrameSpec:
    """A synthetic tracking frame, shaped like the BQP tracker's per-frame QP.

    Attributes
    ----------
    n_targets : int
        Number of targets ``n`` (blocks).
    target_size : float
        Head template side ``s``, pixels.
    spacing : float
        Mean distance between neighbouring targets, pixels (dense crowd: ~1.5 sizes).
    grid : int
        Candidates per side of the search window (2x target size): ``grid**2`` candidates.
    drop : float
        Fraction of candidates removed at random per target (so ``k`` varies, ~50-100).
    motion_sigma : float
        Std of the motion prediction error, pixels (``c_m``, Eq. 6).
    zeta : float
        Weight of the motion term ``c_m`` (Eq. 1).
    w_sp, w_g : float
        Weights of the spatial-proximity ``C_sp`` (Eq. 9) and grouping ``C_g`` (Eq. 10) terms.
    group_fraction : float
        Fraction of targets walking in groups of 2-5 (grouping term).
    proximity_sigma, proximity_cutoff : float
        ``sigma`` of Eq. 9 in target sizes (paper: 0.5), and the cutoff in ``sigma``.
    group_sigma, group_cutoff : float
        ``sigma`` of Eq. 10 in target sizes, and the cutoff on ``| |p_i - p_j| - e_ij |``
        in ``sigma``.
    noise : float
        Std of the appearance-response noise.
    """

    n_targets: int = 100
    target_size: float = 12.0
    spacing: float = 18.0
    grid: int = 9
    drop: float = 0.2
    motion_sigma: float = 3.0
    zeta: float = 0.3
    w_sp: float = 1.0
    w_g: float = 1.0
    group_fraction: float = 0.3
    proximity_sigma: float = 0.5
    proximity_cutoff: float = 2.0
    group_sigma: float = 0.25
    group_cutoff: float = 2.5
    noise: float = 0.05

    def __post_init__(self) -> None:
        if self.n_targets < 0:
            raise ValueError(f"FrameSpec.n_targets must be >= 0, got {self.n_targets}")
        if self.grid < 1:
            raise ValueError(f"FrameSpec.grid must be >= 1, got {self.grid}")
        if not 0.0 <= self.drop < 1.0:
            raise ValueError(f"FrameSpec.drop must be in [0, 1), got {self.drop}")
        for name in (
            "target_size",
            "spacing",
            "motion_sigma",
            "proximity_sigma",
            "proximity_cutoff",
            "group_sigma",
            "group_cutoff",
        ):
            if getattr(self, name) <= 0:
                raise ValueError(f"FrameSpec.{name} must be > 0, got {getattr(self, name)}")


def _normalised_laplacian(S: sp.coo_matrix, l: int, sign: float) -> sp.csc_matrix:
    """``I + sign D^-1/2 S D^-1/2`` on the nodes with an edge (isolated nodes: 0 row/column).

    ``sign = -1``: normalised Laplacian; ``sign = +1``: signless normalised Laplacian. Both
    are PSD (eigenvalues of ``D^-1/2 S D^-1/2`` lie in [-1, 1]).
    """
    S = S.tocsr()
    d = np.asarray(S.sum(axis=1)).ravel()
    has = d > 0
    inv = np.zeros(l)
    inv[has] = 1.0 / np.sqrt(d[has])
    Dm = sp.diags(inv)
    return (sp.diags(has.astype(float)) + sign * (Dm @ S @ Dm)).tocsc()


def synthetic_frame_qp(spec: FrameSpec, rng: np.random.Generator) -> BlockQP:
    """A relaxed QP shaped like a real frame of the BQP tracker (see :class:`FrameSpec`).

    Returns a :class:`BlockQP` with ``c = c_a + zeta c_m`` and ``Q = w_sp C_sp + w_g C_g``.
    As in :mod:`tracker.bqp.quadratic`, ``C_sp`` is the *signless* normalised Laplacian
    ``I + D^-1/2 S D^-1/2`` (the paper's ``I - ...`` would reward co-selecting close
    candidates) and ``C_g = I - D^-1/2 Gamma D^-1/2``; both are PSD, so ``Q`` is PSD.
    """
    n = spec.n_targets
    if n == 0:
        return BlockQP(np.zeros(0), sp.csc_matrix((0, 0)), np.zeros(1, dtype=np.int64))
    sigma = spec.proximity_sigma * spec.target_size
    sigma_g = spec.group_sigma * spec.target_size
    sigma_a = spec.target_size / 4.0
    side = int(np.ceil(np.sqrt(n)))
    lattice = (
        np.stack(np.meshgrid(np.arange(side), np.arange(side), indexing="ij"), axis=-1)
        .reshape(-1, 2)[:n]
        .astype(float)
    )
    true = (lattice + 0.25 * rng.standard_normal((n, 2))) * spec.spacing
    pred = true + spec.motion_sigma * rng.standard_normal((n, 2))

    # Candidate grid over each search window (2x the target size), centred on the prediction.
    half = spec.target_size
    ticks = np.linspace(-half, half, spec.grid)
    offs = np.stack(np.meshgrid(ticks, ticks, indexing="ij"), axis=-1).reshape(-1, 2)
    pts, owner = [], []
    for i in range(n):
        keep = rng.random(offs.shape[0]) >= spec.drop
        keep[np.argmin(np.linalg.norm(offs, axis=1))] = True
        pts.append(pred[i] + offs[keep])
        owner.append(np.full(int(keep.sum()), i, dtype=np.int64))
    p = np.concatenate(pts)
    owner = np.concatenate(owner)
    l = p.shape[0]
    block_ptr = np.concatenate([[0], np.cumsum(np.bincount(owner, minlength=n))]).astype(np.int64)

    # Appearance (c_a): correlation-filter response peaks at the target and, weaker, at
    # look-alike neighbours; motion (c_m, Eq. 6): Gaussian prediction around ``pred``.
    tree_t = cKDTree(true)
    resp = np.exp(-np.sum((p - true[owner]) ** 2, axis=1) / (2 * sigma_a**2))
    for a, b in tree_t.query_pairs(2.0 * spec.target_size):
        for i, j in ((a, b), (b, a)):
            sl = slice(block_ptr[i], block_ptr[i + 1])
            look = 0.3 + 0.4 * rng.random()
            resp[sl] = np.maximum(
                resp[sl], look * np.exp(-np.sum((p[sl] - true[j]) ** 2, axis=1) / (2 * sigma_a**2))
            )
    c_a = -(resp + spec.noise * rng.standard_normal(l))
    c_m = 1.0 - np.exp(-np.sum((p - pred[owner]) ** 2, axis=1) / (2 * spec.motion_sigma**2))
    c = c_a + spec.zeta * c_m

    # C_sp (Eq. 9): S_ij between candidates of different targets within the cutoff.
    pairs = cKDTree(p).query_pairs(spec.proximity_cutoff * sigma, output_type="ndarray")
    pairs = pairs[owner[pairs[:, 0]] != owner[pairs[:, 1]]]
    sv = np.exp(-np.sum((p[pairs[:, 0]] - p[pairs[:, 1]]) ** 2, axis=1) / (2 * sigma**2))
    S = sp.coo_matrix(
        (
            np.concatenate([sv, sv]),
            (
                np.concatenate([pairs[:, 0], pairs[:, 1]]),
                np.concatenate([pairs[:, 1], pairs[:, 0]]),
            ),
        ),
        shape=(l, l),
    )
    Q = spec.w_sp * _normalised_laplacian(S, l, +1.0)

    # C_g (Eq. 10): groups of 2-5 nearby targets, an MST per group; Gamma between candidates
    # of MST neighbours rewards keeping the previous inter-target distance e_ij.
    if spec.w_g > 0 and spec.group_fraction > 0 and n > 1:
        rows, cols, vals = [], [], []
        in_group = np.zeros(n, dtype=bool)
        for seed_t in rng.permutation(n):
            if in_group[seed_t] or in_group.mean() >= spec.group_fraction:
                continue
            size = int(rng.integers(2, 6))
            members = [m for m in tree_t.query(true[seed_t], k=min(size, n))[1] if not in_group[m]]
            if len(members) < 2:
                continue
            in_group[members] = True
            d = np.linalg.norm(true[members][:, None] - true[members][None], axis=-1)
            mst = minimum_spanning_tree(sp.csr_matrix(d + 1e-9 * (d == 0))).tocoo()
            for a, b in zip(mst.row, mst.col, strict=True):
                i, j = members[a], members[b]
                e_ij = d[a, b]
                ii = np.arange(block_ptr[i], block_ptr[i + 1])
                jj = np.arange(block_ptr[j], block_ptr[j + 1])
                dist = np.linalg.norm(p[ii][:, None] - p[jj][None], axis=-1)
                dev = dist - e_ij
                keep = np.abs(dev) <= spec.group_cutoff * sigma_g
                gam = np.exp(-(dev**2) / (2 * sigma_g**2))
                r, cc = np.nonzero(keep)
                rows += [ii[r], jj[cc]]
                cols += [jj[cc], ii[r]]
                vals += [gam[keep], gam[keep]]
        if rows:
            G = sp.coo_matrix(
                (np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(l, l)
            )
            Q = Q + spec.w_g * _normalised_laplacian(G, l, -1.0)
    Q = sp.csc_matrix(Q)
    Q = (Q + Q.T) * 0.5  # exact symmetry after the float round-off of D^-1/2 S D^-1/2
    return BlockQP(c, sp.csc_matrix(Q), block_ptr)


# ------------------------------------------------------------------ the tracker contract
def _choices(cls: type, name: str) -> tuple[Any, ...]:
    """The valid values of a choice field, read from the dataclass's own validation."""
    import ast
    import re

    try:
        cls(**{name: "\x00not-a-choice"})
    except ValueError as exc:
        m = re.search(r"must be one of (\(.*\)), got", str(exc))
        if m:
            return tuple(ast.literal_eval(m.group(1)))
    return ()


def perturbations(params: Any) -> dict[str, Any]:
    """One valid changed value per field of a parameter dataclass (for contract checks).

    Numbers are scaled up (or down when that is out of range), booleans flipped, choices
    moved to another valid choice. Fields with no valid other value are left out.
    """
    cls = type(params)
    out: dict[str, Any] = {}
    for f in fields(cls):
        v = getattr(params, f.name)
        if isinstance(v, bool):
            tries: list[Any] = [not v]
        elif isinstance(v, int):
            tries = [v + 1, v - 1]
        elif isinstance(v, float):
            tries = [v * 1.5 + 0.05, v * 0.5, v - 0.05]
        elif isinstance(v, str):
            tries = [c for c in _choices(cls, f.name) if c != v]
        else:
            continue
        for t in tries:
            try:
                replace(params, **{f.name: t})
            except ValueError:
                continue
            out[f.name] = t
            break
    return out


def scene_detections(scene: Scene, first: int = 0) -> list[tuple[np.ndarray, np.ndarray]]:
    """Perfect detections of a scene: per frame ``(xyxy (m, 4), confidence (m,))`` head boxes
    of the template size around every present target (confidence 0.9), none before frame
    ``first``."""
    half = scene.template_size / 2.0
    out = []
    for t, pts in enumerate(scene.points):
        p = pts[np.isfinite(pts).all(1) & (t >= first)]
        out.append((np.concatenate([p - half, p + half], axis=1), np.full(len(p), 0.9)))
    return out


def set_params_scenes() -> tuple[Scene, ...]:
    """The scenes of :func:`check_set_params`: four textured targets of four colours, one
    faster than the default search radius, over 16 frames (past the default template refresh
    of 10), so that search, update and refresh parameters change the tracks; and 24 look-alike
    targets packed 11 px apart in two opposite flows, where the solver's term weights and the
    neighbourhood parameters decide."""
    sparse = make_scene(
        [[12, 20], [60, 30], [100, 70], [30, 70]], [[5, 1], [0, 2], [-1, 0], [2, -2]], n_frames=16
    )
    starts = [[12 + 11 * (k % 8), 20 + 11 * (k // 8)] for k in range(24)]
    flows = [[2 if (k // 8) % 2 == 0 else -2, k % 3 - 1] for k in range(24)]
    packed = make_scene(
        starts, flows, n_frames=14, shape=(80, 112), colours=np.tile([[40, 40, 40]], (24, 1))
    )
    return sparse, packed


def check_set_params(make_tracker: Callable[[Any], Any], scene: Scene | None = None) -> list[str]:
    """Every parameter given through ``set_params`` after ``init`` acts as if given at start.

    For each field of the tracker's parameters, tracker X starts with the changed value and
    tracker Y starts with the default, then receives the changed value by ``set_params``
    right after ``init``. Both must give identical tracks on the rest of each scene
    (:func:`set_params_scenes`, or ``scene``): a value copied into the tracker's state at
    ``init`` and silently ignored afterwards shows up here. Fields in ``fixed_params`` must be
    refused with a ``ValueError`` naming them.

    Parameters
    ----------
    make_tracker : callable
        ``make_tracker(params_or_None) -> Tracker``.

    Returns
    -------
    The field names checked: refused as fixed, or changing the tracks or confidences on at
    least one scene. A field whose changed value gives the default's tracks on every scene
    could be copied and ignored unseen, so it is not counted:
    ``check_set_params.unexercised`` lists the last call's.
    """
    scenes = (scene,) if scene is not None else set_params_scenes()

    def make(params: Any, sc: Scene) -> Any:
        tr = make_tracker(params)
        if hasattr(tr, "use_detections"):
            # tracking-by-detection: perfect head boxes from frame 1 on, so that init (which
            # associates frame 0's detections with the parameters of that moment) sees none
            tr.use_detections(scene_detections(sc, first=1))
        return tr

    def started(params: Any, sc: Scene) -> Any:
        tr = make(params, sc)
        tr.init(sc.frames[0], sc.ids, sc.points[0], sc.template_size)
        return tr

    def state(tr: Any, frame: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        ids, pts = tr.step(frame)
        return ids, pts, np.array(tr.confidence, copy=True)

    def same(a: tuple, b: tuple) -> bool:
        return all(np.array_equal(u, v) for u, v in zip(a, b, strict=True))

    first = make_tracker(None)
    params, fixed = first.params, type(first).fixed_params
    defaults = []
    for sc in scenes:
        base = started(None, sc)
        defaults.append([state(base, f) for f in sc.frames[1:]])
    checked: list[str] = []
    check_set_params.unexercised = []
    for name, value in perturbations(params).items():
        new = replace(params, **{name: value})
        if name in fixed:
            y = started(None, scenes[0])
            try:
                y.set_params(new)
            except ValueError as exc:
                if name not in str(exc):
                    raise AssertionError(f"refusal of {name} does not name it: {exc}") from exc
                checked.append(name)
                continue
            raise AssertionError(f"fixed parameter {name} was accepted mid-sequence")
        moved = False
        for sc, default in zip(scenes, defaults, strict=True):
            y = started(None, sc)
            y.set_params(new)
            if y.params is not new:
                raise AssertionError(f"set_params({name}={value!r}) did not replace params")
            x = started(new, sc)
            for t, frame in enumerate(sc.frames[1:], 1):
                got, want = state(y, frame), state(x, frame)
                if not same(got, want):
                    raise AssertionError(
                        f"{type(y).__name__}: {name}={value!r} given by "
                        f"set_params after init differs at frame {t} from the "
                        "same value given at start"
                    )
                moved = moved or not same(want, default[t - 1])
        if moved:
            checked.append(name)
        else:  # no effect on any scene: nothing was compared
            check_set_params.unexercised.append(name)
    return checked


# ------------------------------------------------------------------ the whole contract
def _position_check(tracker: Any, got: np.ndarray, want: np.ndarray, what: str) -> None:
    """``got`` against ``want``: ``(T, n, 2)``, or ``(T, 2)`` for one target."""
    tol = float(getattr(type(tracker), "position_tolerance_px", 0.0))
    name = type(tracker).__name__
    got, want = np.asarray(got, np.float64), np.asarray(want, np.float64)
    if want.ndim == 2:  # one target's track
        got, want = got[:, None], want[:, None]
    if not np.array_equal(np.isnan(got), np.isnan(want)):
        raise AssertionError(f"{name}: {what}: tracked where the person is absent, or lost")
    ok = np.isnan(want) | (np.abs(got - want) <= tol)
    if not ok.all():
        t, j = np.argwhere(~ok.all(-1))[0]
        raise AssertionError(
            f"{name}: {what}: frame {t}, target {j} at {got[t, j].tolist()}, "
            f"expected {want[t, j].tolist()} (tolerance {tol:g} px)"
        )


def _track_scene(tracker: Any, sc: Scene, births: Any = None) -> Any:
    pts = sc.points[0]
    present = np.isfinite(pts).all(1)
    return tracker.track(sc.frames, sc.ids[present], pts[present], sc.template_size, births=births)


def _expect_error(what: str, match: str, call: Callable[[], Any]) -> None:
    try:
        call()
    except ValueError as exc:
        if match not in str(exc):
            raise AssertionError(f"{what}: the error does not say {match!r}: {exc}") from exc
        return
    raise AssertionError(f"{what}: accepted without a ValueError")


def _check_exact_scene(factory: Callable[..., Any]) -> None:
    from tracker.base import TrackResult

    sc = make_scene(
        [[20, 20], [90, 20], [100, 75], [25, 75]], [[2, 1], [-2, 1], [-2, 0], [1, -1]], n_frames=12
    )
    tr = factory()
    res = _track_scene(tr, sc)
    if not isinstance(res, TrackResult) or res.positions.shape != (12, 4, 2):
        raise AssertionError(f"{type(tr).__name__}: track() must return (12, 4, 2) positions")
    if not np.array_equal(res.ids, sc.ids):
        raise AssertionError(f"{type(tr).__name__}: ids {res.ids} != {sc.ids}")
    _position_check(tr, res.positions, sc.points, "hand-built scene")
    if not res.timings.get("total", 0) > 0:
        raise AssertionError(f"{type(tr).__name__}: timings['total'] not recorded")


def _check_zero_targets(factory: Callable[..., Any]) -> None:
    sc = make_scene(np.zeros((0, 2)), np.zeros((0, 2)), n_frames=4)
    res = factory().track(sc.frames, [], np.zeros((0, 2)), 8)
    if res.positions.shape != (4, 0, 2) or res.ids.shape != (0,):
        raise AssertionError("zero targets must give (T, 0, 2) positions and no ids")


def _check_empty_frames(factory: Callable[..., Any]) -> None:
    flat = [np.full((60, 80, 3), 100, np.uint8)] * 5
    res = factory().track(flat, [1, 2], np.array([[20.0, 20.0], [60.0, 40.0]]), 8)
    if not np.isfinite(res.positions).all():
        t, j = np.argwhere(~np.isfinite(res.positions).all(-1))[0]
        raise AssertionError(
            f"on textureless frames target {j} is gone at frame {t} (its track ended, or it "
            f"gave a NaN point; last at {res.positions[max(t - 1, 0), j].tolist()})"
        )
    if np.abs(res.positions - res.positions[0]).max() > 4 * 5:
        raise AssertionError("on textureless frames a point wandered beyond its search range")


def _check_border(factory: Callable[..., Any]) -> None:
    sc = make_scene([[3, 3], [124, 50]], [[2, 0], [0, 2]], n_frames=8, shape=(96, 128))
    tr = factory()
    res = _track_scene(tr, sc)
    tol = max(2.0, float(getattr(type(tr), "position_tolerance_px", 0.0)))
    off = np.abs(res.positions - sc.points).max(-1)  # NaN where lost
    bad = ~(off <= tol)
    if bad.any():
        t, j = np.argwhere(bad)[0]
        raise AssertionError(
            f"targets at the image border: frame {t}, target {j} at "
            f"{res.positions[t, j].tolist()}, expected {sc.points[t, j].tolist()} "
            f"(lost, or further than {tol:g} px)"
        )


def _check_leaving_and_births(factory: Callable[..., Any]) -> None:
    sc = make_scene(
        [[110, 30], [30, 60], [60, 20]],
        [[3, 0], [1, 0], [0, 2]],
        n_frames=14,
        shape=(96, 128),
        birth_frames=[0, 0, 5],
    )
    tr = factory()
    res = _track_scene(tr, sc, births={5: (sc.ids[2:], sc.points[5, 2:])})
    if not np.array_equal(res.ids, sc.ids):
        raise AssertionError(f"births: ids {res.ids} != {sc.ids}")
    gone = np.flatnonzero(np.isnan(sc.points[:, 0, 0]))[0]  # id 1 leaves on the right
    lag = _max_lost(tr) if getattr(type(tr), "position_tolerance_px", 0.0) else 0
    if not np.isnan(res.positions[gone + 1 + lag :, 0]).all():
        raise AssertionError("a target that left the image is still tracked")
    if not np.isnan(res.positions[:5, 2]).all():
        raise AssertionError("a target is tracked before its birth frame")
    _position_check(tr, res.positions[5:, 2], sc.points[5:, 2], "a target born at frame 5")
    _position_check(tr, res.positions[:, 1], sc.points[:, 1], "a target that stays")
    # motion() (the tuning environment reads it after every step) keeps up with both
    tr = factory()
    tr.init(sc.frames[0], sc.ids[:2], sc.points[0, :2], sc.template_size)
    for t in range(1, len(sc.frames)):
        tr.step(sc.frames[t], (sc.ids[2:], sc.points[5, 2:]) if t == 5 else None)
        motion = np.asarray(tr.motion())
        if motion.shape != tr.points.shape or not np.isfinite(motion).all():
            raise AssertionError(
                f"motion() after frame {t} is {motion.dtype} {motion.shape}, expected "
                f"{tr.points.shape} finite (keep the motion state in step in _add and _remove)"
            )


def _check_vanishing(factory: Callable[..., Any]) -> None:
    sc = make_scene(
        [[20, 20], [110, 20], [100, 70], [30, 70]],
        [[2, 1], [0, 1], [-1, 0], [1, -1]],
        n_frames=20,
        death_frames=[20, 8, 20, 20],
    )
    tr = factory()
    res = _track_scene(tr, sc)
    max_lost = _max_lost(tr)
    if not max_lost > 0:
        raise AssertionError(
            "params.max_lost must be > 0 for tracks to end on lost evidence: give the params "
            "max_lost and lost_ratio fields (tracker.base.Tracker, 'What a tracker of your own "
            "needs')"
        )
    if not np.isnan(res.positions[8 + max_lost :, 1]).all():
        raise AssertionError(
            f"a person who vanished at frame 8 is still tracked {max_lost} frames later"
        )
    _position_check(tr, res.positions[:8, 1], sc.points[:8, 1], "before vanishing")
    for j in (0, 2, 3):
        _position_check(tr, res.positions[:, j], sc.points[:, j], "beside a vanishing person")


def _max_lost(tracker: Any) -> int:
    return int(getattr(tracker.params, "max_lost", 0) or 0)


def _check_bad_input(factory: Callable[..., Any]) -> None:
    sc = make_scene([[20, 20]], [[1, 0]], n_frames=3)
    tr = factory()
    _expect_error("step before init", "init", lambda: tr.step(sc.frames[0]))
    _expect_error(
        "duplicate ids", "duplicate", lambda: tr.init(sc.frames[0], [1, 1], np.zeros((2, 2)), 8)
    )
    _expect_error(
        "a point outside the frame",
        "outside",
        lambda: tr.init(sc.frames[0], [1], np.array([[500.0, 5.0]]), 8),
    )
    _expect_error(
        "template_size 1",
        "template_size",
        lambda: tr.init(sc.frames[0], [1], np.array([[5.0, 5.0]]), 1),
    )
    tr.init(sc.frames[0], [1], sc.points[0], 8)
    _expect_error("a smaller frame", "mismatched frame sizes", lambda: tr.step(sc.frames[1][:50]))
    _expect_error(
        "a birth with a used id",
        "already used",
        lambda: tr.step(sc.frames[1], births=(np.array([1]), np.array([[40.0, 40.0]]))),
    )
    _expect_error("a float frame", "uint8", lambda: tr.step(sc.frames[1].astype(np.float32)))
    _expect_error("no frames", "no frames", lambda: tr.track([], [1], sc.points[0], 8))
    says = "takes" if type(tr).params_class is not None else "has no parameters"
    _expect_error("params of another type", says, lambda: factory().set_params(object()))


def _check_deterministic(factory: Callable[..., Any]) -> None:
    sc = make_scene([[20, 20], [26, 28], [60, 50]], [[2, 1], [2, 1], [-1, 1]], n_frames=10)
    a = _track_scene(_fed(factory(), sc), sc).positions
    b = _track_scene(_fed(factory(), sc), sc).positions
    if not np.array_equal(a, b, equal_nan=True):
        raise AssertionError("two runs on the same scene gave different tracks")


def _fed(tracker: Any, sc: Scene) -> Any:
    if hasattr(tracker, "use_detections"):
        tracker.use_detections(scene_detections(sc))
    return tracker


def _check_params(factory: Callable[..., Any]) -> None:
    tr = factory()
    cls = type(tr).params_class
    if cls is None:  # no parameters: nothing to set
        return
    if not isinstance(tr.params, cls):
        raise AssertionError(f"{type(tr).__name__}.params is not a {cls.__name__}")
    if not check_set_params(factory):
        raise AssertionError(f"{type(tr).__name__}: no parameter could be checked")


POINT_CHECKS: dict[str, Callable[[Callable[..., Any]], None]] = {
    "exact positions on a hand-built scene": _check_exact_scene,
    "zero targets": _check_zero_targets,
    "textureless frames": _check_empty_frames,
    "targets at the border": _check_border,
    "leaving targets end, births start": _check_leaving_and_births,
    "tracks end where people vanish in view": _check_vanishing,
    "bad input is refused by name": _check_bad_input,
}
"""Checks of trackers that follow the given targets (``id_mapping == "same"``)."""
COMMON_CHECKS: dict[str, Callable[[Callable[..., Any]], None]] = {
    "deterministic": _check_deterministic,
    "set_params: every parameter acts as if given at start": _check_params,
}
"""Checks of every tracker, tracking-by-detection included."""


def contract_checks(factory: Callable[..., Any]) -> dict[str, Callable[[Callable[..., Any]], None]]:
    """The checks of :func:`check_tracker_contract` that apply to ``factory``'s tracker."""
    point = getattr(type(factory()), "id_mapping", "same") == "same"
    return {**(POINT_CHECKS if point else {}), **COMMON_CHECKS}


def check_tracker_contract(factory: Callable[..., Any]) -> list[str]:
    """Run the whole tracker contract on ``factory``'s tracker; raise on the first breach.

    ``factory(params=None) -> Tracker`` makes a fresh tracker (default parameters when
    ``params`` is ``None``), e.g. ``tracker.registry.get("bqp").create`` or a class of your own.
    Point trackers (``id_mapping == "same"``, the default) must recover tiny hand-built scenes
    exactly (within the class's ``position_tolerance_px``), handle zero targets, textureless
    frames, the image border, people who leave or vanish, births and bad input; every tracker
    must be deterministic and honour ``set_params`` (:func:`check_set_params`).

    Returns the names of the checks passed; raises ``AssertionError`` naming the tracker and
    the check otherwise.

    >>> from tracker.registry import get
    >>> check_tracker_contract(get("ncc").create)[:2]
    ['exact positions on a hand-built scene', 'zero targets']
    """
    passed = []
    for name, check in contract_checks(factory).items():
        try:
            check(factory)
        except AssertionError as exc:
            raise AssertionError(f"tracker contract, {name}: {exc}") from exc
        except Exception as exc:  # noqa: BLE001 - the tracker broke: say in which check
            raise AssertionError(f"tracker contract, {name}: {type(exc).__name__}: {exc}") from exc
        passed.append(name)
    return passed
