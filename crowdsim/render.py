"""Top-down renderer: trajectories -> frames of small people (SPEC §4).

The renderer consumes state; it never simulates (STYLE habit 6). Two steps:

1. :func:`prepare_agents` turns :class:`~crowdsim.trajectories.Trajectories` and a
   :class:`~crowdsim.camera.Camera` into an :class:`AgentTracks` struct of arrays: head
   centres in pixels ``(T, N, 2)``, headings ``(T, N)`` (with sway), poses ``(T, N)`` (gait
   phase and head turn), one appearance per agent.
2. :class:`SceneRenderer` draws frame ``t`` in compiled passes (no per-pixel Python): the
   pre-built textured ground (static clutter baked in, cropped to follow the camera jitter,
   bilinear between whole pixels so it moves by the same offset as the people) with
   illumination drift, flicker and sensor noise straight to ``uint8``; then every person
   stamped from a :class:`~crowdsim.appearance_model.SpriteBank` (per-pose, per-orientation,
   per-sub-pixel-phase coverages with the shadow baked in, mixed with the person's colours),
   lit and noised the same way; then moving shadows, defocus and motion blur. People are
   composited in depth order in horizontal bands processed in parallel; a pixel belongs to one
   band, so the result does not depend on the thread count. Video-codec and JPEG compression
   happen when the frame is written (:mod:`synth_data.writer`).

Depth order: the camera tilts about the image ``u`` axis with its far side at the top, so on
the ground plane depth falls as ``v`` grows; people are drawn top to bottom and a nearer
person covers the people behind it (exactly the painter's order; for an untilted camera the
order is arbitrary but fixed). With ``appearance.heads_on_top`` the heads are drawn again, in
the same order, after all bodies: seen from above only heads can hide heads. With
``visibility=`` the renderer also reports, per person, the
visible fraction of its head disc in that drawing: a per-pixel owner buffer records the last
person whose body covers the pixel (shadows do not occlude), and the head's coverage owned by
its own person, inside the frame, over its whole coverage is the visible fraction.

Sprites keep their template size over the whole frame, also under a tilted camera (the
ground-truth box is the template, SPEC §2); the tilt moves people through the homography.

All randomness derives from the ``seed`` given to the functions, split with
:class:`numpy.random.SeedSequence` per purpose, so a frame depends only on
``(trajectories, camera, appearance, seed, t)``.

Ground truth: the head centre of agent ``n`` in frame ``t`` is ``AgentTracks.pixels[t, n]``,
drawn to within ``1 / (2 * subpixel)`` pixels. The MOT rows are built by
:func:`synth_data.mot.gt_rows`, not here.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np
from numba import njit, prange

from crowdsim.appearance_model import (
    ALPHA_EPS,
    HAIR_COLOURS,
    HEAD_RADIUS,
    PALETTES,
    PROMINENT_COLOURS,
    SOLID_COVERAGE,
    AppearanceParams,
    SpriteBank,
    build_sprite_bank,
    cluster_weights,
)
from crowdsim.camera import Camera
from crowdsim.events import Event, light_factor, noise_sigma, of_kind, parse_events
from crowdsim.trajectories import Trajectories

BODY_WIDTH_M: float = 0.5
"""Shoulder width in metres that one template spans; default scale = template_px / this."""
HEADING_MIN_SPEED: float = 0.15
"""Below this speed (m/s) an agent keeps its previous heading."""
HEADING_WINDOW: int = 2
"""Half window (rows) of the central difference used for headings."""
SWAY_STRIDE_M: float = 1.4
"""Distance walked per full gait period (two steps), metres: drives sway, arms and bob."""
NOISE_POOL_MARGIN: int = 61
"""Extra rows/columns of the sensor-noise pool; each frame reads it at a random offset."""
STAMP_BANDS: int = 16
"""Horizontal bands composited in parallel (the result does not depend on this number)."""
NOISE_POOL_SCALE: float = 16.0
"""Standard normal noise is stored as int8 times this factor."""
MOVING_SHADOW_DARKNESS: float = 0.4
"""Relative darkening at the centre of a moving shadow."""
MOVING_SHADOW_SPEED: tuple[float, float] = (0.5, 1.5)
"""Range of the moving shadows' speeds, m/s."""
DISTRACTOR_KINDS: tuple[str, ...] = ("bollard", "litter", "marking")
"""Static clutter baked into the ground, drawn in equal proportions."""
BYTES_PER_PIXEL = 64
"""Render working set per frame pixel (float32 ground, noise pool, frame, JPEG); measured
45-61 B at 2048..8192 px sides."""
BYTES_PER_AGENT_ROW = 192
"""Working set per (frame, agent) cell (positions, pixels, headings, sway, poses, gt rows);
measured 182 B: peak RSS 392 MB at 801 frames and 829 MB at 3,201 frames of 1,000 people at
640x360 (2026-11-28, `/usr/bin/time -v`); the 128 B before came from 107 B measured on an
earlier renderer."""


def render_bytes(width: int, height: int, n_frames: int, n_agents: int) -> int:
    """Estimated peak working set (bytes) of rendering ``n_frames`` frames of ``n_agents``
    people at ``width`` x ``height`` px, their trajectories included."""
    return BYTES_PER_PIXEL * width * height + BYTES_PER_AGENT_ROW * n_frames * n_agents


@dataclass
class AgentTracks:
    """What the renderer needs per agent and frame.

    Attributes
    ----------
    ids : (N,) int64
        Trajectory ids.
    pixels : (T, N, 2) float64
        Head centres in pixels (camera jitter included), NaN where absent.
    heading : (T, N) float64
        Image-plane facing angle in radians (``atan2(dv, du)``), sway included.
    appearance : (N,) int64
        Index of each agent's look (see :func:`assign_appearance`).
    prominent : (N,) bool
        Agents drawn with a distinct colour.
    pose : (T, N) int64, optional
        Sprite pose (gait phase and head turn, see
        :func:`crowdsim.appearance_model.build_sprite_bank`); zeros when omitted.
    """

    ids: np.ndarray
    pixels: np.ndarray
    heading: np.ndarray
    appearance: np.ndarray
    prominent: np.ndarray
    pose: np.ndarray | None = None

    def __post_init__(self) -> None:
        if self.pose is None:
            self.pose = np.zeros(self.pixels.shape[:2], np.int64)

    @property
    def n_frames(self) -> int:
        return self.pixels.shape[0]


def default_px_per_m(template_px: int) -> float:
    """Scale at which one template spans :data:`BODY_WIDTH_M`."""
    return template_px / BODY_WIDTH_M


def _seeds(seed: int, n: int) -> list[np.random.SeedSequence]:
    return np.random.SeedSequence([int(seed), 0xC0DE]).spawn(n)


def assign_appearance(
    prominent: np.ndarray | None, n: int, params: AppearanceParams, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray]:
    """``(appearance (n,), prominent (n,))`` for ``n`` agents.

    If ``prominent`` is given and has any True entry it is used; otherwise a fraction
    ``params.prominent_fraction`` is drawn. Prominent agents get one of the distinct
    colours, the rest a variant of a cluster drawn with :func:`cluster_weights`.
    """
    if prominent is None or not np.any(prominent):
        prominent = rng.random(n) < params.prominent_fraction
    prominent = np.asarray(prominent, dtype=bool)
    n_var = params.n_clusters * params.variants_per_cluster
    cluster = rng.choice(params.n_clusters, size=n, p=cluster_weights(params))
    variant = rng.integers(0, params.variants_per_cluster, n)
    app = cluster * params.variants_per_cluster + variant
    app[prominent] = n_var + rng.integers(0, len(PROMINENT_COLOURS), int(prominent.sum()))
    return app.astype(np.int64), prominent


def _headings(pixels: np.ndarray, speed_ok: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """``(T, N)`` facing angles from pixel-space central differences, forward/back filled."""
    t_len, n = pixels.shape[:2]
    k = HEADING_WINDOW
    lo = np.clip(np.arange(t_len) - k, 0, t_len - 1)
    hi = np.clip(np.arange(t_len) + k, 0, t_len - 1)
    d = pixels[hi] - pixels[lo]
    ang = np.arctan2(d[..., 1], d[..., 0])
    valid = speed_ok & np.isfinite(ang)
    out = np.full((t_len, n), np.nan)
    last = rng.uniform(-math.pi, math.pi, n)  # agents that never move face a random way
    first = np.where(valid.any(axis=0), ang[np.argmax(valid, axis=0), np.arange(n)], last)
    last = first
    for t in range(t_len):
        last = np.where(valid[t], ang[t], last)
        out[t] = last
    return out


def _poses(
    gait: np.ndarray, t_len: int, dt: float, params: AppearanceParams, rng: np.random.Generator
) -> np.ndarray:
    """``(T, N)`` sprite poses ``g * H + h`` from gait phases and seeded head turns."""
    n_g, n_h = params.gait_phases, params.head_turns
    pose = np.zeros(gait.shape, np.int64)
    if n_g > 1:
        pose += np.mod(np.rint(gait * (n_g / (2 * math.pi))), n_g).astype(np.int64) * n_h
    if n_h > 1:
        n = gait.shape[1]
        period = params.head_turn_period_s * rng.uniform(0.5, 1.5, n)
        phase = rng.uniform(0, 2 * math.pi, n)
        turn = np.sin(2 * math.pi * (np.arange(t_len) * dt)[:, None] / period + phase)
        pose += np.rint(turn * ((n_h - 1) / 2.0)).astype(np.int64) + (n_h - 1) // 2
    return pose


def prepare_agents(
    traj: Trajectories, camera: Camera, params: AppearanceParams, seed: int
) -> AgentTracks:
    """Project trajectories and derive headings, sway, poses and appearances (all seeded)."""
    s_app, s_head, s_sway, s_turn = _seeds(seed, 4)
    pixels = camera.project_trajectories(traj.positions)
    n = traj.n_agents
    app, prominent = assign_appearance(
        traj.attributes.get("prominent"), n, params, np.random.default_rng(s_app)
    )
    # headings and the distance walked go the short way round a periodic axis's seam (they
    # had turned a person crossing it round for a few frames and jumped its gait by a period)
    pos = traj.unwrapped()
    k = HEADING_WINDOW
    t_len = traj.n_steps
    lo = np.clip(np.arange(t_len) - k, 0, t_len - 1)
    hi = np.clip(np.arange(t_len) + k, 0, t_len - 1)
    span = np.maximum(hi - lo, 1)[:, None] * traj.dt
    with np.errstate(invalid="ignore"):
        speed = np.linalg.norm(pos[hi] - pos[lo], axis=-1) / span
        speed_ok = speed > HEADING_MIN_SPEED
    # People face the way they walk on the ground: camera shake moves the image, it does not
    # turn them (and the drone profile turns the drawn canvas as a whole). Headings from the
    # shaken pixels turned ucf9 seq6's slow runners frame by frame: BQP at 15 px on its uncoded
    # frames, 88.1 % static, 64.4 % shaken, 82.5 % shaken with headings from the ground.
    walk_px = pixels if not (camera.moves or traj.period > 0) else camera.project(pos)
    heading = _headings(walk_px, speed_ok, np.random.default_rng(s_head))
    gait = np.zeros((t_len, n))
    if (params.sway_deg > 0 or params.gait_phases > 1) and t_len > 1:
        # One gait phase per agent, advanced by the distance walked: sway, arms and bob
        # move in step, and a standing person keeps its pose.
        step = np.zeros((t_len, n))
        with np.errstate(invalid="ignore"):
            step[1:] = np.nan_to_num(np.linalg.norm(pos[1:] - pos[:-1], axis=-1))
        walked = np.cumsum(step, axis=0)
        phase0 = np.random.default_rng(s_sway).uniform(0, 2 * math.pi, n)
        gait = 2 * math.pi * walked / SWAY_STRIDE_M + phase0
        if params.sway_deg > 0:
            heading = heading + math.radians(params.sway_deg) * np.sin(gait)
    pose = _poses(gait, t_len, traj.dt, params, np.random.default_rng(s_turn))
    return AgentTracks(
        ids=traj.ids.copy(),
        pixels=pixels,
        heading=heading,
        appearance=app,
        prominent=prominent,
        pose=pose,
    )


# ---------------------------------------------------------------------------- kernels
# Frame = ground * illumination + noise, computed straight into uint8 (one parallel pass);
# people are then composited onto it with the same illumination and noise at their pixels:
#   out = out * (1 - alpha) + gain * premultiplied_colour + alpha * noise
# which equals rendering the people first and lighting/noising the result afterwards. The
# premultiplied colour is mixed on the fly from the sprite's part coverages (clothing, hair,
# face) and the person's three colours. Images are passed as (rows, columns * 3) views so the
# inner loops run over contiguous memory and LLVM can vectorise them.
@njit(cache=True, nogil=True, inline="always")
def _lit(g, gain, noise, noise_scale):  # pragma: no cover - numba
    # one ground value lit and noised, rounded into uint8: both ground passes call this, so
    # a shaken frame and a still one are lit alike
    v = g * gain + noise * noise_scale + np.float32(0.5)
    return np.uint8(min(max(v, np.float32(0.0)), np.float32(255.0)))


@njit(cache=True, nogil=True, parallel=True)
def _ground_pass(
    ground, oy, ox3, noise, ny, nx3, noise_scale, g0, gain_x, gy, out
):  # pragma: no cover - numba
    h, w3 = out.shape
    inv_h = np.float32(1.0 / h)
    for y in prange(h):
        gyy = g0 + gy * (y * inv_h - np.float32(0.5))
        grow = ground[oy + y]
        nrow = noise[ny + y]
        orow = out[y]
        for q in range(w3):
            g = np.float32(grow[ox3 + q])
            orow[q] = _lit(g, gyy + gain_x[q], np.float32(nrow[nx3 + q]), noise_scale)


@njit(cache=True, nogil=True, parallel=True)
def _ground_pass_subpixel(
    ground, oy, ox3, fy, fx, noise, ny, nx3, noise_scale, g0, gain_x, gy, out
):  # pragma: no cover - numba
    # _ground_pass with the ground sampled at (oy + y + fy, ox + x + fx): bilinear weights of
    # the four ground pixels around it (the camera's shake is not a whole number of pixels,
    # and the people it moves are drawn at their exact positions).
    h, w3 = out.shape
    inv_h = np.float32(1.0 / h)
    one = np.float32(1.0)
    w00 = (one - fy) * (one - fx)
    w01 = (one - fy) * fx
    w10 = fy * (one - fx)
    w11 = fy * fx
    for y in prange(h):
        gyy = g0 + gy * (y * inv_h - np.float32(0.5))
        g0row = ground[oy + y]
        g1row = ground[oy + y + 1]
        nrow = noise[ny + y]
        orow = out[y]
        for q in range(w3):
            c = ox3 + q
            g = (
                w00 * np.float32(g0row[c])
                + w01 * np.float32(g0row[c + 3])
                + w10 * np.float32(g1row[c])
                + w11 * np.float32(g1row[c + 3])
            )
            orow[q] = _lit(g, gyy + gain_x[q], np.float32(nrow[nx3 + q]), noise_scale)


@njit(cache=True, nogil=True, parallel=True)
def _stamp(
    out,
    cover,
    alpha,
    solid,
    spans,
    tiles,
    idx,
    app,
    x0,
    y0,
    noise,
    ny,
    nx3,
    noise_scale,
    g0,
    gx,
    gy,
    band_rows,
    band_first,
    band_last,
    owner,
    owner_base,
    use_owner,
):  # pragma: no cover - numba
    # Horizontal bands are composited in parallel; a pixel belongs to exactly one band and
    # within a band agents are drawn in the given (depth) order, so the result equals a
    # serial pass. The owner buffer gets owner_base + the rank of the last person whose body
    # covers a pixel (values below owner_base are left over from earlier frames).
    h, w3 = out.shape
    w = w3 // 3
    z = spans.shape[1]
    half = np.float32(z / 2.0)
    for b in prange(band_rows.shape[0] - 1):
        ylo = band_rows[b]
        yhi = band_rows[b + 1]
        for k in range(band_first[b], band_last[b]):
            s = idx[k]
            a_k = app[k]
            oy = y0[k]
            ox = x0[k]
            ox3 = 3 * ox
            # Illumination is smooth: one gain per sprite (its centre) is exact to ~1e-4.
            g = (
                g0
                + gx * ((ox + half) / np.float32(w) - np.float32(0.5))
                + gy * ((oy + half) / np.float32(h) - np.float32(0.5))
            )
            tc = tiles[a_k, 0]
            th = tiles[a_k, 1]
            ts = tiles[a_k, 2]
            for i in range(max(0, ylo - oy), min(z, yhi - oy)):
                y = oy + i
                lo = spans[s, i, 0]
                hi = spans[s, i, 1]
                if ox3 + lo < 0:
                    lo = -ox3
                if ox3 + hi > w3:
                    hi = w3 - ox3
                orow = out[y]
                nrow = noise[ny + y]
                cc = cover[s, i, 0]
                ch = cover[s, i, 1]
                cs = cover[s, i, 2]
                arow = alpha[s, i]
                for q in range(lo, hi):
                    a = arow[q]
                    col = cc[q] * tc[q] + ch[q] * th[q] + cs[q] * ts[q]
                    v = (
                        np.float32(orow[ox3 + q]) * (np.float32(1.0) - a)
                        + col * g
                        + a * noise_scale * np.float32(nrow[nx3 + q])
                        + np.float32(0.5)
                    )
                    orow[ox3 + q] = np.uint8(min(max(v, np.float32(0.0)), np.float32(255.0)))
                if use_owner:
                    srow = solid[s, i]
                    wrow = owner[y]
                    for j in range(lo // 3, hi // 3):
                        if srow[j]:
                            wrow[ox + j] = owner_base + k


@njit(cache=True, nogil=True, parallel=True)
def _head_visibility(
    head, solid, idx, x0, y0, owner, owner_base, r0, r1, c0, c1, view, vw, vh, vis
):  # pragma: no cover - numba
    # Visible fraction of each person's head: over the head-disc pixels the person owns when
    # drawn alone (solid), the coverage-weighted share that is inside the frame and still
    # owned by the person after everyone is drawn (frame clipping counts as hidden). The
    # frame is the drawing's, or the view ``(vw, vh)`` that the affine ``view`` (2, 3) maps
    # the drawing into (the drone profile's canvas); the identity and the drawing's size
    # test exactly the drawing's bounds.
    h, w = owner.shape
    for k in prange(idx.shape[0]):
        s = idx[k]
        tot = np.float32(0.0)
        own = np.float32(0.0)
        for i in range(r0, r1):
            y = y0[k] + i
            for j in range(c0, c1):
                c = head[s, i, j]
                if c > 0 and solid[s, i, j]:
                    tot += c
                    x = x0[k] + j
                    if 0 <= y < h and 0 <= x < w and owner[y, x] == owner_base + k:
                        u = view[0, 0] * x + view[0, 1] * y + view[0, 2]
                        v = view[1, 0] * x + view[1, 1] * y + view[1, 2]
                        if -0.5 <= u < vw - 0.5 and -0.5 <= v < vh - 0.5:
                            own += c
        vis[k] = own / tot if tot > 0 else 0.0


@njit(cache=True, nogil=True)
def _shade(out, masks, x0, y0):  # pragma: no cover - numba
    # Multiply the frame by (1 - mask) under every moving shadow (masks: (n, S, 3S)).
    h, w3 = out.shape
    sz = masks.shape[1]
    for k in range(masks.shape[0]):
        ox3 = 3 * x0[k]
        for i in range(max(0, -y0[k]), min(sz, h - y0[k])):
            orow = out[y0[k] + i]
            mrow = masks[k, i]
            for q in range(max(0, -ox3), min(3 * sz, w3 - ox3)):
                v = np.float32(orow[ox3 + q]) * (np.float32(1.0) - mrow[q]) + np.float32(0.5)
                orow[ox3 + q] = np.uint8(min(v, np.float32(255.0)))


def _draw_distractors(
    base: np.ndarray, params: AppearanceParams, px_per_m: float, rng: np.random.Generator
) -> None:
    """Bake static head-like clutter (bollards, litter, road-marking dashes) into ``base``.

    ``base`` is the ``(H, W, 3)`` float32 ground; ``params.distractor_density`` items per
    square metre at scale ``px_per_m``, a third of each kind on average.
    """
    height, width = base.shape[:2]
    area_m2 = height * width / (px_per_m * px_per_m)
    n = int(rng.poisson(params.distractor_density * area_m2))
    if n == 0:
        return
    s = float(params.template_px)
    ss = 16  # cv2 fixed-point sub-pixel drawing
    kinds = rng.integers(0, len(DISTRACTOR_KINDS), n)
    centres = rng.uniform((0.0, 0.0), (width, height), (n, 2))
    sizes = rng.uniform(0.8, 1.3, n)
    angles = rng.uniform(0.0, 180.0, n)
    shades = rng.uniform(-12.0, 12.0, n)
    palette = np.array(PALETTES[params.palette] + PROMINENT_COLOURS[:4], np.float64)
    picks = rng.integers(0, len(palette), n)
    ground = np.array(params.ground_bgr, np.float64)
    for k in range(n):  # scene setup, once per sequence
        c = (int(round(centres[k, 0] * ss)), int(round(centres[k, 1] * ss)))
        r = HEAD_RADIUS * s * sizes[k]
        kind = DISTRACTOR_KINDS[kinds[k]]
        if kind == "bollard":  # a dark disc the size of a head, with a shadow
            shadow = (
                int(round((centres[k, 0] + 0.3 * s) * ss)),
                int(round((centres[k, 1] + 0.2 * s) * ss)),
            )
            cv2.circle(
                base,
                shadow,
                int(round(1.1 * r * ss)),
                tuple(float(v) for v in 0.7 * ground),
                -1,
                cv2.LINE_AA,
                4,
            )
            colour = np.array(HAIR_COLOURS[0], np.float64) + 20.0 + shades[k]
            cv2.circle(
                base, c, int(round(r * ss)), tuple(float(v) for v in colour), -1, cv2.LINE_AA, 4
            )
        elif kind == "litter":  # a small blob of clothing-like colour
            axes = (int(round(0.8 * r * ss)), int(round(0.5 * r * ss)))
            colour = palette[picks[k]] + shades[k]
            _filled_ellipse(base, c, axes, float(angles[k]), colour)
        else:  # a painted dash
            axes = (int(round(0.45 * s * sizes[k] * ss)), int(round(0.08 * s * ss)))
            _filled_ellipse(base, c, axes, float(angles[k]), np.full(3, 225.0 + shades[k]))


def _filled_ellipse(img: np.ndarray, centre, axes, angle: float, colour) -> None:
    """An anti-aliased filled ellipse at 4 bits of sub-pixel precision (as the circles)."""
    cv2.ellipse(
        img, centre, axes, angle, 0, 360, tuple(float(v) for v in colour), -1, cv2.LINE_AA, 4
    )


def make_ground(
    height: int, width: int, params: AppearanceParams, px_per_m: float, rng: np.random.Generator
) -> np.ndarray:
    """``(height, width, 3)`` uint8 ground: multi-scale noise, paving, static clutter."""
    base = np.empty((height, width, 3), np.float32)
    base[:] = np.array(params.ground_bgr, np.float32)
    if params.ground_texture > 0:
        tex = np.zeros((height, width), np.float32)
        total = 0.0
        for sigma, weight in ((0.7, 0.5), (3.0, 0.35), (20.0, 0.3)):
            layer = rng.standard_normal((height, width)).astype(np.float32)
            layer = cv2.GaussianBlur(layer, (0, 0), sigma)
            layer /= max(float(layer.std()), 1e-6)
            tex += weight * layer
            total += weight * weight
        tex *= params.ground_texture / math.sqrt(total)
        tint = rng.uniform(0.85, 1.15, 3).astype(np.float32)
        base += tex[..., None] * tint
    if params.paving_m > 0:
        step = params.paving_m * px_per_m
        if step >= 4:
            yy, xx = np.mgrid[0:height, 0:width]
            joint = ((np.mod(xx, step) < 1.0) | (np.mod(yy, step) < 1.0)).astype(np.float32)
            base -= joint[..., None] * (0.25 * np.array(params.ground_bgr, np.float32))
    if params.distractor_density > 0:
        _draw_distractors(base, params, px_per_m, rng)
    return np.clip(np.rint(base), 0, 255).astype(np.uint8)


class SceneRenderer:
    """Draws frames for one camera, appearance and seed.

    Parameters
    ----------
    camera : Camera
        Frame size and jitter; the ground is rendered with a margin so it moves with the jitter.
        With the drone profile (``camera.drone_on``) a larger canvas (:meth:`Camera.canvas`)
        is drawn and warped into the view each frame; the sensor noise is part of the canvas,
        so the bilinear warp softens it a little.
    params : AppearanceParams
        Look of people and scene.
    seed : int
        Seed of the ground, sprite colours, illumination, flicker, shadows and noise.
    fps : float
        Frames per second (sets the illumination drift and the moving shadows' speed).
    events : sequence of Event, optional
        Scheduled changes (:mod:`crowdsim.events`); the renderer applies the ``lighting``
        and ``noise`` ones (a ``shake`` burst lives in the camera, which the truth shares).
    """

    def __init__(
        self,
        camera: Camera,
        params: AppearanceParams,
        seed: int,
        fps: float,
        events: Sequence[Event] = (),
    ) -> None:
        if not (fps > 0):
            raise ValueError(f"fps must be > 0, got {fps!r}")
        self.camera = camera
        self.params = params
        self.fps = float(fps)
        self.seed = int(seed)
        # lighting and noise events (shake bursts live in the camera, which the truth shares)
        self.events = of_kind(parse_events(events), ("lighting", "noise"))
        self._canvas: SceneRenderer | None = None
        # where a drawn head counts as in the frame: the drawing itself, or (the drone
        # profile's canvas) the view it is warped into, as (affine (2, 3), width, height)
        self._view = (np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]), camera.width, camera.height)
        if camera.drone_on:
            # The drone profile: draw a larger, drone-free canvas, then warp it into the view.
            canvas, self._canvas_offset = camera.canvas()
            self._canvas = SceneRenderer(canvas, params, seed, fps, self.events)
            self.bank = self._canvas.bank
            self.margin = self._canvas.margin
            self._views = np.zeros((0, 2, 3))
            return
        s_bank, s_ground, s_noise, s_light, s_shadow = np.random.SeedSequence(
            [int(seed), 0x5CE4E]
        ).spawn(5)
        self.bank: SpriteBank = build_sprite_bank(params, np.random.default_rng(s_bank))
        self.margin = camera.ground_margin
        h, w = camera.height, camera.width
        m = self.margin
        self.ground = make_ground(
            h + 2 * m, w + 2 * m, params, camera.px_per_m, np.random.default_rng(s_ground)
        )
        rng = np.random.default_rng(s_noise)
        self.noise = np.clip(
            rng.standard_normal((h + NOISE_POOL_MARGIN, w + NOISE_POOL_MARGIN, 3), dtype=np.float32)
            * NOISE_POOL_SCALE,
            -127,
            127,
        ).astype(np.int8)
        # Flat (rows, columns * 3) layouts for the kernels; coverages repeated per channel.
        b = self.bank
        k, z = b.alpha.shape[:2]
        self._ground2 = self.ground.reshape(self.ground.shape[0], -1)
        self._noise2 = self.noise.reshape(self.noise.shape[0], -1)
        self._cover3 = np.ascontiguousarray(np.repeat(b.cover.transpose(0, 1, 3, 2), 3, axis=3))
        self._alpha3 = np.ascontiguousarray(np.repeat(b.alpha, 3, axis=2))
        self._tiles = np.ascontiguousarray(np.tile(b.colours, (1, 1, z)))
        self._spans3 = (3 * b.spans).astype(np.int64)
        rows = np.flatnonzero(b.head.any(axis=(0, 2)))
        cols = np.flatnonzero(b.head.any(axis=(0, 1)))
        self._head_box = (int(rows[0]), int(rows[-1]) + 1, int(cols[0]), int(cols[-1]) + 1)
        self._head_solid = b.head >= SOLID_COVERAGE
        if params.heads_on_top:
            # Head layer: the head disc's hair and face over everything drawn.
            head_vis = b.head > ALPHA_EPS
            any_row = head_vis.any(axis=2)
            hlo = np.where(any_row, np.argmax(head_vis, axis=2), 0)
            hhi = np.where(any_row, z - np.argmax(head_vis[:, :, ::-1], axis=2), 0)
            self._head_spans3 = (3 * np.stack([hlo, hhi], -1)).astype(np.int64)
            self._head_alpha3 = np.ascontiguousarray(np.repeat(b.head, 3, axis=2))
            self._head_tiles = self._tiles.copy()
            self._head_tiles[:, 0] = 0.0  # no clothing inside the head layer
        self._owner = np.full((h, w), -1, np.int32)
        self._owner_next = 0  # owner ids of a frame start here: no clearing between frames
        self._no_owner = np.zeros((1, 1), np.int32)
        light = np.random.default_rng(s_light)
        self._phases = light.uniform(0, 2 * math.pi, 3)
        self._jitter = np.zeros((0, 2))
        self._blur = None
        if params.motion_blur_px >= 1:
            n = int(round(params.motion_blur_px))
            kern = np.zeros((n | 1, n | 1), np.float32)
            kern[(n | 1) // 2, :] = 1.0
            rot = cv2.getRotationMatrix2D(
                ((n | 1) / 2 - 0.5, (n | 1) / 2 - 0.5), float(light.uniform(-30, 30)), 1.0
            )
            kern = cv2.warpAffine(kern, rot, kern.shape[::-1])
            self._blur = kern / kern.sum()
        self._init_moving_shadows(np.random.default_rng(s_shadow))

    def _init_moving_shadows(self, rng: np.random.Generator) -> None:
        """Seeded start points, velocities (px/frame) and ``(n, S, 3S)`` darkening masks."""
        p = self.params
        cam = self.camera
        h, w = cam.height, cam.width
        n = 0
        if p.moving_shadow_density > 0:
            n = int(rng.poisson(p.moving_shadow_density * h * w / cam.px_per_m**2))
        d = p.moving_shadow_m * cam.px_per_m
        sz = int(math.ceil(2.0 * d)) + 3
        self._shadow_size = sz
        self._shadow_start = rng.uniform((0.0, 0.0), (w + sz, h + sz), (n, 2))
        ang = rng.uniform(0, 2 * math.pi, n)
        speed = rng.uniform(*MOVING_SHADOW_SPEED, n) * cam.px_per_m / self.fps
        self._shadow_vel = speed[:, None] * np.column_stack([np.cos(ang), np.sin(ang)])
        masks = np.zeros((n, sz, sz), np.float32)
        c = (sz - 1) / 2.0
        for k in range(n):  # scene setup, once per sequence
            axes = (int(round(0.5 * d * 16)), int(round(0.5 * d * rng.uniform(0.6, 1.0) * 16)))
            cv2.ellipse(
                masks[k],
                (int(round(c * 16)), int(round(c * 16))),
                axes,
                float(np.degrees(ang[k])),
                0,
                360,
                1.0,
                -1,
                cv2.LINE_AA,
                4,
            )
            masks[k] = cv2.GaussianBlur(masks[k], (0, 0), max(0.6, 0.15 * d))
        self._shadow_masks = np.ascontiguousarray(
            np.repeat(masks * np.float32(MOVING_SHADOW_DARKNESS), 3, axis=2)
        )

    # ------------------------------------------------------------------ per frame
    def _frame_jitter(self, t: int) -> np.ndarray:
        if self.camera.shake_px == 0:
            return np.zeros(2)
        if t >= len(self._jitter):
            self._jitter = self.camera.jitter(max(t + 1, 2 * len(self._jitter)))
        return self._jitter[t]

    def illumination(self, t: int) -> tuple[float, float, float]:
        """``(gain, x gradient, y gradient)`` of frame ``t``, flicker and lighting events
        included."""
        p = self.params
        a = p.illumination_drift
        w = 2 * math.pi * t / (p.illumination_period_s * self.fps)
        ph = self._phases
        gain = (
            1.0 + a * math.sin(w + ph[0]),
            a * math.sin(0.61 * w + ph[1]),
            a * math.sin(0.37 * w + ph[2]),
        )
        if p.flicker > 0:
            f = 1.0 + p.flicker * float(
                np.random.default_rng([self.seed, 0xF11C, int(t)]).standard_normal()
            )
            f = max(f, 0.0)
            gain = (gain[0] * f, gain[1] * f, gain[2] * f)
        if self.events:
            f = light_factor(self.events, t)
            gain = (gain[0] * f, gain[1] * f, gain[2] * f)
        return gain

    def moving_shadow_corners(self, t: int) -> np.ndarray:
        """``(n, 2)`` int64 top-left pixel corners of the moving shadows' masks in frame ``t``.

        Shadows drift at constant velocity and wrap around the frame (plus one mask size),
        so their number in view stays constant.
        """
        sz = self._shadow_size
        cam = self.camera
        period = np.array([cam.width + sz, cam.height + sz], np.float64)
        pos = np.mod(self._shadow_start + self._shadow_vel * t, period) - sz
        return np.floor(pos).astype(np.int64)

    def render(
        self,
        t: int,
        pixels: np.ndarray,
        heading: np.ndarray,
        appearance: np.ndarray,
        out: np.ndarray | None = None,
        pose: np.ndarray | None = None,
        visibility: np.ndarray | None = None,
    ) -> np.ndarray:
        """Frame ``t`` as ``(H, W, 3)`` uint8 BGR.

        Parameters
        ----------
        t : int
            0-based frame index (drives jitter of the ground, illumination, flicker, moving
            shadows and noise).
        pixels : (n, 2) float
            Head centres in pixels of the view (NaN rows are skipped): with the drone profile,
            where the ground truth puts them (:meth:`Camera.project_trajectories`).
        heading : (n,) float
            Facing angles, radians (on the ground, before the drone profile's rotation).
        appearance : (n,) int
            Appearance index per agent.
        out : (H, W, 3) uint8, optional
            Buffer to draw into.
        pose : (n,) int, optional
            Sprite pose per agent (default 0).
        visibility : (n,) float64, optional
            Filled with the visible fraction of each agent's head disc in this drawing (after
            occlusion by people drawn in front and clipping by the frame): NaN for NaN rows,
            0 for agents entirely outside. Computed before the moving shadows and blurs,
            which do not hide a head.
        """
        pixels, heading, appearance, pose = self._checked_agents(pixels, heading, appearance, pose)
        if self._canvas is not None:
            return self._render_view(t, pixels, heading, appearance, out, pose, visibility)
        cam = self.camera
        h, w = cam.height, cam.width
        m = self.margin
        oy = ox = m
        fy = fx = 0.0
        if m:
            # The scene moves by the shake j: frame pixel p shows ground pixel p + m - j, which
            # lies between whole pixels (kept one pixel inside the margin for the bilinear
            # neighbour; the shake is clipped to the margin, 4 standard deviations and more).
            sy, sx = np.clip(m - self._frame_jitter(t)[::-1], 0.0, 2 * m - 1.0)
            oy, ox = int(sy), int(sx)
            fy, fx = sy - oy, sx - ox
        if out is None:
            out = np.empty((h, w, 3), np.uint8)
        g0, gx, gy = (np.float32(v) for v in self.illumination(t))
        rng = np.random.default_rng([self.seed, 0x7015E, int(t)])
        ny, nx = (int(v) for v in rng.integers(0, NOISE_POOL_MARGIN + 1, 2))
        sigma = self.params.noise_sigma
        if self.events:
            sigma = noise_sigma(self.events, t, sigma)
        nscale = np.float32(sigma / NOISE_POOL_SCALE)
        gain_x = gx * (np.arange(w, dtype=np.float32) / np.float32(w) - np.float32(0.5))
        out2 = out.reshape(h, w * 3)
        lit = (self._noise2, ny, 3 * nx, nscale, g0, np.repeat(gain_x, 3), gy, out2)
        if fy or fx:
            _ground_pass_subpixel(self._ground2, oy, 3 * ox, np.float32(fy), np.float32(fx), *lit)
        else:
            _ground_pass(self._ground2, oy, 3 * ox, *lit)
        pixels = np.asarray(pixels, np.float64)
        n_all = len(pixels)
        if visibility is not None:
            if visibility.shape != (n_all,):
                raise ValueError(f"visibility must have shape ({n_all},), got {visibility.shape}")
            visibility[:] = np.where(np.isfinite(pixels).all(axis=1), 0.0, np.nan)
        bank = self.bank
        z = bank.size
        if n_all:
            ok = np.isfinite(pixels[:, 0]) & np.isfinite(pixels[:, 1])
            # Cull agents whose sprite cannot touch the frame.
            with np.errstate(invalid="ignore"):
                ok &= (
                    (pixels[:, 0] > -z)
                    & (pixels[:, 0] < w + z)
                    & (pixels[:, 1] > -z)
                    & (pixels[:, 1] < h + z)
                )
            sel = np.flatnonzero(ok)
            pts = pixels[sel]
            hd = heading[sel]
            ap = appearance[sel]
            ps = np.zeros(len(sel), np.int64) if pose is None else pose[sel]
            p = bank.subpixel
            f = pts - (z - 1) / 2.0
            base = np.floor(f)
            phase = np.rint((f - base) * p).astype(np.int64)
            carry = phase == p
            base += carry
            phase[carry] = 0
            nb = bank.n_bins
            bins = np.mod(np.rint(hd * (nb / (2 * math.pi))), nb).astype(np.int64)
            idx = bank.index(ps, bins, phase[:, 1], phase[:, 0])
            x0 = base[:, 0].astype(np.int64)
            y0 = base[:, 1].astype(np.int64)
            # Depth order = top to bottom (see the module docstring); row-ordered writes also
            # keep the frame and noise rows in cache.
            order = np.argsort(y0, kind="stable")
            y0 = y0[order]
            x0 = x0[order]
            idx = idx[order]
            rows = np.linspace(0, h, STAMP_BANDS + 1).astype(np.int64)
            first = np.searchsorted(y0, rows[:-1] - z + 1, side="left")
            last = np.searchsorted(y0, rows[1:], side="left")
            use_owner = visibility is not None
            owner = self._owner if use_owner else self._no_owner
            base_id = 0
            if use_owner:
                if self._owner_next + len(sel) >= np.iinfo(np.int32).max:
                    owner.fill(-1)
                    self._owner_next = 0
                base_id = self._owner_next
                self._owner_next += len(sel)
            on_top = self.params.heads_on_top
            passes = [(self._alpha3, bank.solid, self._spans3, self._tiles, not on_top)]
            if on_top:  # heads are the highest point: only other heads can hide them
                passes.append(
                    (self._head_alpha3, self._head_solid, self._head_spans3, self._head_tiles, True)
                )
            for alpha, solid, spans, tiles, owns in passes:
                _stamp(
                    out2,
                    self._cover3,
                    alpha,
                    solid,
                    spans,
                    tiles,
                    idx,
                    ap[order],
                    x0,
                    y0,
                    self._noise2,
                    ny,
                    3 * nx,
                    nscale,
                    g0,
                    gx,
                    gy,
                    rows,
                    first,
                    last,
                    owner,
                    base_id,
                    use_owner and owns,
                )
            if use_owner and len(sel):
                vis = np.empty(len(sel), np.float32)
                _head_visibility(
                    bank.head,
                    self._head_solid if on_top else bank.solid,
                    idx,
                    x0,
                    y0,
                    owner,
                    base_id,
                    *self._head_box,
                    *self._view,
                    vis,
                )
                visibility[sel[order]] = vis
        if len(self._shadow_masks):
            corners = self.moving_shadow_corners(t)
            _shade(out2, self._shadow_masks, corners[:, 0].copy(), corners[:, 1].copy())
        if self.params.defocus_px > 0:
            cv2.GaussianBlur(
                out, (0, 0), self.params.defocus_px, dst=out, borderType=cv2.BORDER_REFLECT
            )
        if self._blur is not None:
            cv2.filter2D(out, -1, self._blur, dst=out, borderType=cv2.BORDER_REFLECT)
        return out

    def _checked_agents(
        self, pixels, heading, appearance, pose
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None]:
        """:meth:`render`'s agent arrays as float64 / int64, checked: one row per agent, and
        the appearance and pose indices of the drawn (finite) rows inside the sprite bank (an
        index outside it would be read out of bounds by the compiled stamp)."""
        pixels = np.asarray(pixels, np.float64)
        if pixels.ndim != 2 or pixels.shape[1] != 2:
            raise ValueError(f"pixels must have shape (n, 2), got {pixels.shape}")
        n = len(pixels)
        drawn = np.isfinite(pixels).all(axis=1)
        heading = np.asarray(heading, np.float64)
        if heading.shape != (n,):
            raise ValueError(f"heading must have shape ({n},), got {heading.shape}")
        checked = []
        for name, value, count in (
            ("appearance", appearance, len(self.bank.colours)),
            ("pose", pose, self.bank.n_poses),
        ):
            if value is None:
                checked.append(None)
                continue
            value = np.asarray(value)
            if value.shape != (n,):
                raise ValueError(f"{name} must have shape ({n},), got {value.shape}")
            if value.dtype.kind not in "iubf":
                raise ValueError(f"{name} must hold integer indices, got {value.dtype}")
            used = value[drawn]
            # whole numbers in any numeric dtype (a float column read from a file), as before
            if value.dtype.kind == "f" and not (np.isfinite(used) & (used == np.round(used))).all():
                bad = used[~(np.isfinite(used) & (used == np.round(used)))][0]
                raise ValueError(f"{name} must hold integer indices, got {bad}")
            if len(used) and (used.min() < 0 or used.max() >= count):
                raise ValueError(f"{name} must be in [0, {count}), got {used.min()}..{used.max()}")
            out = np.zeros(n, np.int64)  # absent rows are never read
            out[drawn] = used
            checked.append(out)
        return pixels, heading, checked[0], checked[1]

    def _render_view(
        self,
        t: int,
        pixels: np.ndarray,
        heading: np.ndarray,
        appearance: np.ndarray,
        out: np.ndarray | None,
        pose: np.ndarray | None,
        visibility: np.ndarray | None,
    ) -> np.ndarray:
        """The drone profile's frame ``t``: the canvas drawn at the heads' canvas positions
        (the view's map inverted), then warped into the view (bilinear). Headings are the
        canvas's (the ground's); occlusion is measured on the canvas, and a head's share
        that the warp leaves outside the view counts as hidden."""
        if t >= len(self._views):
            self._views = self.camera.drone(max(t + 1, 2 * len(self._views)))
        view = self._views[t]
        lin, shift = view[:, :2], view[:, 2]
        offset = np.asarray(self._canvas_offset, np.float64)
        src = (np.asarray(pixels, np.float64) - shift) @ np.linalg.inv(lin).T + offset
        warp = np.concatenate([lin, (shift - lin @ offset)[:, None]], axis=1)
        h, w = self.camera.height, self.camera.width
        # a head's share outside the view is hidden, as the frame's edge hides it without
        # the drone (it had counted as seen up to the larger canvas's edge)
        self._canvas._view = (warp, w, h)
        canvas = self._canvas.render(t, src, heading, appearance, pose=pose, visibility=visibility)
        if out is None:
            out = np.empty((h, w, 3), np.uint8)
        cv2.warpAffine(
            canvas,
            warp,
            (w, h),
            dst=out,
            flags=cv2.INTER_LINEAR,
            borderMode=cv2.BORDER_REPLICATE,
        )
        return out

    def render_tracks(
        self,
        tracks: AgentTracks,
        t: int,
        out: np.ndarray | None = None,
        visibility: np.ndarray | None = None,
    ) -> np.ndarray:
        """Frame ``t`` of prepared :class:`AgentTracks` (see :meth:`render`)."""
        return self.render(
            t,
            tracks.pixels[t],
            tracks.heading[t],
            tracks.appearance,
            out=out,
            pose=tracks.pose[t],
            visibility=visibility,
        )


def encode_jpeg(frame: np.ndarray, quality: int) -> bytes:
    """JPEG bytes of a BGR frame (deterministic for a given OpenCV build)."""
    ok, buf = cv2.imencode(".jpg", frame, [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
    if not ok:  # pragma: no cover - OpenCV failure
        raise RuntimeError("JPEG encoding failed")
    return buf.tobytes()
