"""Top-down renderer: trajectories -> frames of small people (SPEC §4).

The renderer consumes state; it never simulates (STYLE habit 6). Two steps:

1. :func:`prepare_agents` turns :class:`~crowdsim.trajectories.Trajectories` and a
   :class:`~crowdsim.camera.Camera` into an :class:`AgentTracks` struct of arrays: head
   centres in pixels ``(T, N, 2)``, headings ``(T, N)`` (with sway), one appearance per agent.
2. :class:`SceneRenderer` draws frame ``t`` in two compiled passes (no per-pixel Python):
   the pre-built textured ground (cropped to follow the camera jitter) with illumination
   drift and sensor noise straight to ``uint8``, then every person stamped from a
   :class:`~crowdsim.appearance_model.SpriteBank` (per-orientation, per-sub-pixel-phase
   sprites with the shadow baked in), lit and noised the same way. People are composited
   top to bottom in horizontal bands processed in parallel; a pixel belongs to one band, so
   the result does not depend on the thread count. JPEG compression happens when the frame
   is written (:func:`encode_jpeg`); optional camera motion blur is a final filter.

Sprites keep their template size over the whole frame, also under a tilted camera (the
ground-truth box is the template, SPEC §2); the tilt moves people through the homography.

All randomness derives from the ``seed`` given to the functions, split with
:class:`numpy.random.SeedSequence` per purpose, so a frame depends only on
``(trajectories, camera, appearance, seed, t)``.

Ground truth: the head centre of agent ``n`` in frame ``t`` is ``AgentTracks.pixels[t, n]``,
drawn to within ``1 / (2 * subpixel)`` pixels.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass

# numba's OpenMP threading layer busy-waits between parallel regions by default; on a shared
# 2-core machine that spinning steals the cores from the other thread and from other jobs
# (measured: 1280x720/1k frames/s 65 -> 255 with PASSIVE). A user's own setting wins.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import cv2
import numpy as np
from numba import njit, prange

from crowdsim.appearance_model import (
    PROMINENT_COLOURS,
    AppearanceParams,
    SpriteBank,
    build_sprite_bank,
    cluster_weights,
)
from crowdsim.camera import Camera
from crowdsim.trajectories import Trajectories

BODY_WIDTH_M: float = 0.5
"""Shoulder width in metres that one template spans; default scale = template_px / this."""
HEADING_MIN_SPEED: float = 0.15
"""Below this speed (m/s) an agent keeps its previous heading."""
HEADING_WINDOW: int = 2
"""Half window (rows) of the central difference used for headings."""
SWAY_STRIDE_M: float = 1.4
"""Distance walked per full shoulder-sway period (two steps), metres."""
NOISE_POOL_MARGIN: int = 61
"""Extra rows/columns of the sensor-noise pool; each frame reads it at a random offset."""
STAMP_BANDS: int = 16
"""Horizontal bands composited in parallel (the result does not depend on this number)."""
NOISE_POOL_SCALE: float = 16.0
"""Standard normal noise is stored as int8 times this factor."""


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
    """

    ids: np.ndarray
    pixels: np.ndarray
    heading: np.ndarray
    appearance: np.ndarray
    prominent: np.ndarray

    @property
    def n_frames(self) -> int:
        return self.pixels.shape[0]


def default_px_per_m(template_px: int) -> float:
    """Scale at which one template spans :data:`BODY_WIDTH_M`."""
    return template_px / BODY_WIDTH_M


def _seeds(seed: int, n: int) -> list[np.random.SeedSequence]:
    return np.random.SeedSequence([int(seed), 0xC0DE]).spawn(n)


def assign_appearance(prominent: np.ndarray | None, n: int, params: AppearanceParams,
                      rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
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


def prepare_agents(traj: Trajectories, camera: Camera, params: AppearanceParams,
                   seed: int) -> AgentTracks:
    """Project trajectories and derive headings, sway and appearances (all seeded)."""
    s_app, s_head, s_sway = _seeds(seed, 3)
    pixels = camera.project_trajectories(traj.positions)
    n = traj.n_agents
    app, prominent = assign_appearance(traj.attributes.get("prominent"), n, params,
                                       np.random.default_rng(s_app))
    pos = traj.positions
    k = HEADING_WINDOW
    t_len = traj.n_steps
    lo = np.clip(np.arange(t_len) - k, 0, t_len - 1)
    hi = np.clip(np.arange(t_len) + k, 0, t_len - 1)
    span = np.maximum(hi - lo, 1)[:, None] * traj.dt
    with np.errstate(invalid="ignore"):
        speed = np.linalg.norm(pos[hi] - pos[lo], axis=-1) / span
        speed_ok = speed > HEADING_MIN_SPEED
    heading = _headings(pixels, speed_ok, np.random.default_rng(s_head))
    if params.sway_deg > 0 and t_len > 1:
        step = np.zeros((t_len, n))
        with np.errstate(invalid="ignore"):
            step[1:] = np.nan_to_num(np.linalg.norm(pos[1:] - pos[:-1], axis=-1))
        walked = np.cumsum(step, axis=0)
        phase0 = np.random.default_rng(s_sway).uniform(0, 2 * math.pi, n)
        heading = heading + math.radians(params.sway_deg) * np.sin(
            2 * math.pi * walked / SWAY_STRIDE_M + phase0)
    return AgentTracks(ids=traj.ids.copy(), pixels=pixels, heading=heading, appearance=app,
                       prominent=prominent)


# ---------------------------------------------------------------------------- kernels
# Frame = ground * illumination + noise, computed straight into uint8 (one parallel pass);
# people are then composited onto it with the same illumination and noise at their pixels:
#   out = out * (1 - alpha) + gain * premultiplied_colour + alpha * noise
# which equals rendering the people first and lighting/noising the result afterwards.
# Images are passed as (rows, columns * 3) views so the inner loops run over contiguous
# memory and LLVM can vectorise them.
@njit(cache=True, nogil=True, parallel=True)
def _ground_pass(ground, oy, ox3, noise, ny, nx3, noise_scale, g0, gain_x, gy,
                 out):  # pragma: no cover - numba
    h, w3 = out.shape
    inv_h = np.float32(1.0 / h)
    for y in prange(h):
        gyy = g0 + gy * (y * inv_h - np.float32(0.5))
        grow = ground[oy + y]
        nrow = noise[ny + y]
        orow = out[y]
        for q in range(w3):
            v = (np.float32(grow[ox3 + q]) * (gyy + gain_x[q])
                 + np.float32(nrow[nx3 + q]) * noise_scale + np.float32(0.5))
            orow[q] = np.uint8(min(max(v, np.float32(0.0)), np.float32(255.0)))


@njit(cache=True, nogil=True, parallel=True)
def _stamp(out, color, alpha, spans, idx, x0, y0, noise, ny, nx3, noise_scale, g0, gx, gy,
           band_rows, band_first, band_last):  # pragma: no cover - numba
    # Horizontal bands are composited in parallel; a pixel belongs to exactly one band and
    # within a band agents are drawn in the given order, so the result equals a serial pass.
    h, w3 = out.shape
    w = w3 // 3
    z = spans.shape[1]
    half = np.float32(z / 2.0)
    for b in prange(band_rows.shape[0] - 1):
        ylo = band_rows[b]
        yhi = band_rows[b + 1]
        for k in range(band_first[b], band_last[b]):
            s = idx[k]
            oy = y0[k]
            ox3 = 3 * x0[k]
            # Illumination is smooth: one gain per sprite (its centre) is exact to ~1e-4.
            g = (g0 + gx * ((x0[k] + half) / np.float32(w) - np.float32(0.5))
                 + gy * ((oy + half) / np.float32(h) - np.float32(0.5)))
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
                crow = color[s, i]
                arow = alpha[s, i]
                for q in range(lo, hi):
                    a = arow[q]
                    v = (np.float32(orow[ox3 + q]) * (np.float32(1.0) - a) + crow[q] * g
                         + a * noise_scale * np.float32(nrow[nx3 + q]) + np.float32(0.5))
                    orow[ox3 + q] = np.uint8(min(max(v, np.float32(0.0)), np.float32(255.0)))


def make_ground(height: int, width: int, params: AppearanceParams, px_per_m: float,
                rng: np.random.Generator) -> np.ndarray:
    """``(height, width, 3)`` uint8 textured ground: multi-scale noise, optional paving."""
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
    return np.clip(np.rint(base), 0, 255).astype(np.uint8)


class SceneRenderer:
    """Draws frames for one camera, appearance and seed.

    Parameters
    ----------
    camera : Camera
        Frame size and jitter; the ground is rendered with a margin so it moves with the jitter.
    params : AppearanceParams
        Look of people and scene.
    seed : int
        Seed of the ground, sprite colours, illumination and noise.
    fps : float
        Frames per second (only sets the illumination drift speed).
    """

    def __init__(self, camera: Camera, params: AppearanceParams, seed: int, fps: float) -> None:
        if not (fps > 0):
            raise ValueError(f"fps must be > 0, got {fps!r}")
        self.camera = camera
        self.params = params
        self.fps = float(fps)
        self.seed = int(seed)
        s_bank, s_ground, s_noise, s_light = np.random.SeedSequence([int(seed), 0x5CE4E]).spawn(4)
        self.bank: SpriteBank = build_sprite_bank(params, np.random.default_rng(s_bank))
        self.margin = int(math.ceil(4 * camera.jitter_px)) + 1 if camera.jitter_px > 0 else 0
        h, w = camera.height, camera.width
        m = self.margin
        self.ground = make_ground(h + 2 * m, w + 2 * m, params, camera.px_per_m,
                                  np.random.default_rng(s_ground))
        rng = np.random.default_rng(s_noise)
        self.noise = np.clip(rng.standard_normal((h + NOISE_POOL_MARGIN, w + NOISE_POOL_MARGIN, 3),
                                                 dtype=np.float32) * NOISE_POOL_SCALE,
                             -127, 127).astype(np.int8)
        # Flat (rows, columns * 3) layouts for the kernels; alpha repeated per channel.
        b = self.bank
        k, z = b.alpha.shape[:2]
        self._ground2 = self.ground.reshape(self.ground.shape[0], -1)
        self._noise2 = self.noise.reshape(self.noise.shape[0], -1)
        self._color3 = np.ascontiguousarray(b.color.reshape(k, z, 3 * z))
        self._alpha3 = np.ascontiguousarray(np.repeat(b.alpha, 3, axis=2))
        self._spans3 = (3 * b.spans).astype(np.int64)
        light = np.random.default_rng(s_light)
        self._phases = light.uniform(0, 2 * math.pi, 3)
        self._jitter = np.zeros((0, 2))
        self._blur = None
        if params.motion_blur_px >= 1:
            n = int(round(params.motion_blur_px))
            kern = np.zeros((n | 1, n | 1), np.float32)
            kern[(n | 1) // 2, :] = 1.0
            rot = cv2.getRotationMatrix2D(((n | 1) / 2 - 0.5, (n | 1) / 2 - 0.5),
                                          float(light.uniform(-30, 30)), 1.0)
            kern = cv2.warpAffine(kern, rot, kern.shape[::-1])
            self._blur = kern / kern.sum()

    # ------------------------------------------------------------------ per frame
    def _frame_jitter(self, t: int) -> np.ndarray:
        if self.camera.jitter_px == 0:
            return np.zeros(2)
        if t >= len(self._jitter):
            self._jitter = self.camera.jitter(max(t + 1, 2 * len(self._jitter)))
        return self._jitter[t]

    def illumination(self, t: int) -> tuple[float, float, float]:
        """``(gain, x gradient, y gradient)`` of frame ``t``."""
        a = self.params.illumination_drift
        w = 2 * math.pi * t / (self.params.illumination_period_s * self.fps)
        p = self._phases
        return (1.0 + a * math.sin(w + p[0]), a * math.sin(0.61 * w + p[1]),
                a * math.sin(0.37 * w + p[2]))

    def render(self, t: int, pixels: np.ndarray, heading: np.ndarray,
               appearance: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        """Frame ``t`` as ``(H, W, 3)`` uint8 BGR.

        Parameters
        ----------
        t : int
            0-based frame index (drives jitter of the ground, illumination and noise).
        pixels : (n, 2) float
            Head centres in pixels (NaN rows are skipped).
        heading : (n,) float
            Facing angles, radians.
        appearance : (n,) int
            Appearance index per agent.
        out : (H, W, 3) uint8, optional
            Buffer to draw into.
        """
        cam = self.camera
        h, w = cam.height, cam.width
        m = self.margin
        oy = ox = m
        if m:
            j = np.clip(np.rint(self._frame_jitter(t)), -m, m).astype(int)
            oy, ox = m - int(j[1]), m - int(j[0])
        if out is None:
            out = np.empty((h, w, 3), np.uint8)
        g0, gx, gy = (np.float32(v) for v in self.illumination(t))
        rng = np.random.default_rng([self.seed, 0x7015E, int(t)])
        ny, nx = (int(v) for v in rng.integers(0, NOISE_POOL_MARGIN + 1, 2))
        nscale = np.float32(self.params.noise_sigma / NOISE_POOL_SCALE)
        gain_x = gx * (np.arange(w, dtype=np.float32) / np.float32(w) - np.float32(0.5))
        out2 = out.reshape(h, w * 3)
        _ground_pass(self._ground2, oy, 3 * ox, self._noise2, ny, 3 * nx, nscale, g0,
                     np.repeat(gain_x, 3), gy, out2)
        pixels = np.asarray(pixels, np.float64)
        bank = self.bank
        z = bank.size
        if len(pixels):
            ok = np.isfinite(pixels[:, 0]) & np.isfinite(pixels[:, 1])
            # Cull agents whose sprite cannot touch the frame.
            with np.errstate(invalid="ignore"):
                ok &= ((pixels[:, 0] > -z) & (pixels[:, 0] < w + z)
                       & (pixels[:, 1] > -z) & (pixels[:, 1] < h + z))
            sel = np.flatnonzero(ok)
            pts = pixels[sel]
            hd = np.asarray(heading, np.float64)[sel]
            ap = np.asarray(appearance, np.int64)[sel]
            p = bank.subpixel
            f = pts - (z - 1) / 2.0
            base = np.floor(f)
            phase = np.rint((f - base) * p).astype(np.int64)
            carry = phase == p
            base += carry
            phase[carry] = 0
            nb = bank.n_bins
            bins = np.mod(np.rint(hd * (nb / (2 * math.pi))), nb).astype(np.int64)
            idx = bank.index(ap, bins, phase[:, 1], phase[:, 0])
            x0 = base[:, 0].astype(np.int64)
            y0 = base[:, 1].astype(np.int64)
            # Draw top to bottom: people lower in the frame overlap those above (right for a
            # tilted camera), and row-ordered writes keep the frame and noise rows in cache.
            order = np.argsort(y0, kind="stable")
            y0 = y0[order]
            rows = np.linspace(0, h, STAMP_BANDS + 1).astype(np.int64)
            first = np.searchsorted(y0, rows[:-1] - z + 1, side="left")
            last = np.searchsorted(y0, rows[1:], side="left")
            _stamp(out2, self._color3, self._alpha3, self._spans3, idx[order], x0[order], y0,
                   self._noise2, ny, 3 * nx, nscale, g0, gx, gy, rows, first, last)
        if self._blur is not None:
            cv2.filter2D(out, -1, self._blur, dst=out, borderType=cv2.BORDER_REFLECT)
        return out

    def render_tracks(self, tracks: AgentTracks, t: int,
                      out: np.ndarray | None = None) -> np.ndarray:
        """Frame ``t`` of prepared :class:`AgentTracks`."""
        return self.render(t, tracks.pixels[t], tracks.heading[t], tracks.appearance, out=out)


def encode_jpeg(frame: np.ndarray, quality: int) -> bytes:
    """JPEG bytes of a BGR frame (deterministic for a given OpenCV build)."""
    ok, buf = cv2.imencode(".jpg", frame, [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
    if not ok:  # pragma: no cover - OpenCV failure
        raise RuntimeError("JPEG encoding failed")
    return buf.tobytes()


def gt_rows(tracks: AgentTracks, camera: Camera, template_px: int,
            mot_ids: np.ndarray) -> np.ndarray:
    """MOT ground-truth rows ``(K, 9)``: one head box per visible agent and frame.

    A row is written when the head centre lies inside the frame. Columns: frame (1-based),
    id, bb_left, bb_top, bb_width, bb_height, conf (1), class (1 = pedestrian), visibility
    (fraction of the box inside the frame). Rows are sorted by frame, then id.
    """
    pix = tracks.pixels
    vis = camera.visible(pix)
    t_idx, n_idx = np.nonzero(vis)
    order = np.lexsort((mot_ids[n_idx], t_idx))
    t_idx, n_idx = t_idx[order], n_idx[order]
    centre = pix[t_idx, n_idx]
    s = float(template_px)
    left = centre[:, 0] - s / 2.0
    top = centre[:, 1] - s / 2.0
    ix = np.clip(np.minimum(left + s, camera.width) - np.maximum(left, 0.0), 0, s)
    iy = np.clip(np.minimum(top + s, camera.height) - np.maximum(top, 0.0), 0, s)
    visibility = ix * iy / (s * s)
    k = len(t_idx)
    return np.column_stack([t_idx + 1, mot_ids[n_idx], left, top, np.full(k, s), np.full(k, s),
                            np.ones(k), np.ones(k), visibility]).astype(np.float64)
