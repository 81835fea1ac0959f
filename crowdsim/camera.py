"""Camera: ground-plane metres -> image pixels (SPEC §2 "Camera").

The ground plane uses the simulator's metres. The image convention is OpenCV's: ``u`` grows
to the right, ``v`` grows downwards, and with no tilt world ``+x`` maps to ``+u`` and world
``+y`` maps to ``+v`` (a top-down view seen from above with ``y`` pointing "south").

A :class:`Camera` is a frozen description (scale, frame size, centre, tilt, jitter, seed); the
maps it computes are pure functions of it, so the same camera always projects the same
trajectories to the same pixels.

* ``px_per_m``: scale at the look-at point (pixels per metre).
* ``tilt_deg``: rotation of a pinhole camera about the image ``u`` axis, away from the nadir.
  ``0`` is a straight top-down (affine) view; larger tilts shrink the far (top) part of the
  frame. The camera sits ``distance_m`` from the look-at point, so the ground is seen through
  the homography ``H = K R [e1 e2 -C]``.
* ``jitter_px``: standard deviation (pixels) of a smooth, seeded per-frame image translation
  (hand-held or wind-shaken camera). ``0`` disables it.
* ``jitter_frames``: correlation time of that shake in frames (default
  :data:`JITTER_CORRELATION_FRAMES`: a slow sway); small values give a fast shake, 1 is
  nearly independent from frame to frame.
* The drone profile, ``drift_px``, ``rotate_deg``, ``zoom`` (all ``0``: off) and
  ``drone_frames``: a slow, smooth, seeded similarity of the whole view about the frame
  centre (:meth:`Camera.drone`), applied after the shake: drift of up to ``drift_px`` per
  axis, rotation of up to ``rotate_deg`` and zoom of up to ``1 +- zoom``, each a sum of three
  sinusoids with periods of 0.5-1.5 ``drone_frames``. The renderer draws a larger canvas
  (:meth:`Camera.canvas`) and warps it, so the view never shows an undrawn border.
* ``shake_events``: shake bursts (:class:`crowdsim.events.Event` of kind ``shake``), each a
  further seeded AR(1) translation of its own standard deviation acting only on its frames.
* ``ground_margin_px``: the renderer draws the ground this far beyond each side of the frame
  at least (:attr:`Camera.ground_margin`; the shake needs :func:`shake_margin`). The ground's
  texture and clutter are drawn for the whole canvas, so two cameras alike but for the shake
  see the same ground only with the same margin: ``crowdsim difficulty`` gives the still
  twin of a shaken spec its margin, and the two then differ by the shake alone.

Examples
--------
>>> cam = Camera(px_per_m=10.0, width=200, height=100, center=(0.0, 0.0))
>>> cam.project(np.array([[0.0, 0.0], [1.0, 2.0]])).round(3).tolist()
[[100.0, 50.0], [110.0, 70.0]]
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from crowdsim.events import Event
from crowdsim.knobs import knob, knobs

JITTER_CORRELATION_FRAMES: float = knob("jitter_frames").default
"""Default time constant (frames) of the camera shake: an AR(1) process with this correlation
time (``Camera.jitter_frames``)."""
DRONE_FRAMES: float = knob("drone_frames").default
"""Default time scale (frames) of the drone profile's drift, rotation and zoom."""
MAX_SIDE: int = 16384
"""Largest width or height of a camera's frame, px (the drone profile's canvas included)."""
FIT_MAX_SIZE: tuple[int, int] = (1920, 1080)
"""Largest frame :meth:`Camera.fit` makes of an extent unless told otherwise, px."""
DRONE_FIELDS: tuple[str, ...] = ("drift_px", "rotate_deg", "zoom", "drone_frames")
"""The drone profile's fields (:meth:`Camera.drone`)."""
MOTION_FIELDS: tuple[str, ...] = tuple(k.name for k in knobs("camera"))
"""The camera's motion fields, one per camera knob (shake and drone profile): what a spec's
``[camera]`` section may set besides the geometry (:func:`motion_values`)."""


def shake_margin(shake_px: float) -> int:
    """Pixels of ground beyond each side of the frame that a shake of standard deviation
    ``shake_px`` needs: 4 deviations and one more pixel for the bilinear neighbour (0 when
    still)."""
    return int(math.ceil(4 * shake_px)) + 1 if shake_px > 0 else 0


def motion_values(camera: Any) -> dict[str, float]:
    """The motion fields of a spec's ``[camera]`` mapping, defaults filled in."""
    return {n: float(camera.get(n, knob(n).default)) for n in MOTION_FIELDS}


@dataclass(frozen=True)
class Camera:
    """A seeded ground-plane camera.

    Attributes
    ----------
    px_per_m : float
        Scale at the look-at point, pixels per metre (> 0).
    width, height : int
        Frame size in pixels (>= 8 each).
    center : (float, float)
        Look-at point in metres; it projects to the frame centre.
    tilt_deg : float
        Tilt away from the nadir in degrees, ``0 <= tilt_deg < 60``.
    distance_m : float
        Camera distance from the look-at point in metres (only matters when tilted).
    jitter_px : float
        Standard deviation of the per-frame translation in pixels (a knob of
        :mod:`crowdsim.knobs`: in ``[0, 200]``).
    jitter_frames : float
        Correlation time of the translation in frames (``> 0``; default 12).
    seed : int
        Seed of the jitter process and of the drone profile.
    drift_px, rotate_deg, zoom, drone_frames : float
        The drone profile (knobs of :mod:`crowdsim.knobs`; ``0``, ``0``, ``0``: off).
    shake_events : tuple of Event
        Shake bursts (kind ``shake``; magnitude: standard deviation in px), added to the
        jitter on their frames only.
    ground_margin_px : int
        Least ground, px, drawn beyond each side of the frame (0: what the shake needs;
        :attr:`ground_margin`). It changes the drawn ground, never where anyone is seen.
    """

    px_per_m: float
    width: int
    height: int
    center: tuple[float, float] = (0.0, 0.0)
    tilt_deg: float = 0.0
    distance_m: float = 60.0
    jitter_px: float = 0.0
    seed: int = 0
    jitter_frames: float = JITTER_CORRELATION_FRAMES
    drift_px: float = 0.0
    rotate_deg: float = 0.0
    zoom: float = 0.0
    drone_frames: float = DRONE_FRAMES
    shake_events: tuple[Event, ...] = ()
    ground_margin_px: int = 0

    def __post_init__(self) -> None:
        if not (math.isfinite(self.px_per_m) and self.px_per_m > 0):
            raise ValueError(f"camera.px_per_m must be > 0, got {self.px_per_m!r}")
        for name in ("width", "height"):
            value = getattr(self, name)
            if not isinstance(value, (int, np.integer)) or value < 8 or value > MAX_SIDE:
                raise ValueError(
                    f"camera.{name} must be an integer in [8, {MAX_SIDE}], got {value!r}"
                )
        if not (0.0 <= self.tilt_deg < 60.0):
            raise ValueError(f"camera.tilt_deg must be in [0, 60), got {self.tilt_deg!r}")
        if not (math.isfinite(self.distance_m) and self.distance_m > 0):
            raise ValueError(f"camera.distance_m must be > 0, got {self.distance_m!r}")
        for k in knobs("camera"):  # the motion knobs: ranges in crowdsim.knobs
            k.check("camera", getattr(self, k.name))
        bad = [e for e in self.shake_events if not (isinstance(e, Event) and e.kind == "shake")]
        if bad:
            raise ValueError(f"camera.shake_events must be shake events, got {bad[0]!r}")
        object.__setattr__(self, "shake_events", tuple(self.shake_events))
        m = self.ground_margin_px
        if not isinstance(m, (int, np.integer)) or isinstance(m, bool) or not 0 <= m <= MAX_SIDE:
            raise ValueError(
                f"camera.ground_margin_px must be an integer in [0, {MAX_SIDE}], got {m!r}"
            )
        object.__setattr__(self, "ground_margin_px", int(m))
        if self.drone_on:
            mx, my = self._canvas_margins()
            if max(self.width + 2 * mx, self.height + 2 * my) > MAX_SIDE:
                raise ValueError(
                    f"camera.drift_px / rotate_deg / zoom ({self.drift_px:g}, "
                    f"{self.rotate_deg:g}, {self.zoom:g}): the drone profile would draw a "
                    f"{self.width + 2 * mx}x{self.height + 2 * my} canvas for a "
                    f"{self.width}x{self.height} view, over {MAX_SIDE} px; lower them"
                )
        if len(self.center) != 2 or not all(math.isfinite(c) for c in self.center):
            raise ValueError(f"camera.center must be two finite numbers, got {self.center!r}")
        object.__setattr__(self, "center", (float(self.center[0]), float(self.center[1])))

    # ------------------------------------------------------------------ construction
    @classmethod
    def fit(
        cls,
        extent: tuple[float, float, float, float],
        *,
        px_per_m: float | None = None,
        size: tuple[int, int] | None = None,
        margin_m: float = 1.0,
        max_size: tuple[int, int] = FIT_MAX_SIZE,
        **kwargs: float,
    ) -> Camera:
        """A camera looking at the centre of ``extent`` = ``(xmin, ymin, xmax, ymax)`` metres.

        With ``size`` but no ``px_per_m`` the scale is the largest that shows the whole extent
        (plus ``margin_m``); with ``px_per_m`` but no ``size`` the frame covers the extent,
        rounded up to even sizes and clipped to ``max_size``; with neither, ``size`` defaults to
        ``max_size``.
        """
        xmin, ymin, xmax, ymax = (float(v) for v in extent)
        w_m = max(xmax - xmin, 0.0) + 2 * margin_m
        h_m = max(ymax - ymin, 0.0) + 2 * margin_m
        if px_per_m is None:
            width, height = size if size is not None else max_size
            px_per_m = min(width / w_m, height / h_m)
        elif size is None:
            width = min(int(math.ceil(w_m * px_per_m / 2.0)) * 2, max_size[0])
            height = min(int(math.ceil(h_m * px_per_m / 2.0)) * 2, max_size[1])
            width, height = max(width, 8), max(height, 8)
        else:
            width, height = size
        center = ((xmin + xmax) / 2.0, (ymin + ymax) / 2.0)
        return cls(
            px_per_m=float(px_per_m), width=int(width), height=int(height), center=center, **kwargs
        )

    # ------------------------------------------------------------------ maps
    @property
    def homography(self) -> np.ndarray:
        """``(3, 3)`` homography from ground metres ``(x, y, 1)`` to pixels ``(u, v, 1)``."""
        cx, cy = self.center
        s = self.px_per_m
        u0, v0 = self.width / 2.0, self.height / 2.0
        if self.tilt_deg == 0.0:
            return np.array([[s, 0.0, u0 - s * cx], [0.0, s, v0 - s * cy], [0.0, 0.0, 1.0]])
        th = -math.radians(self.tilt_deg)  # camera south of the look-at point: top is far
        d = self.distance_m
        # Camera axes in world coordinates: x_c along +x, y_c and z_c (forward) rotated about x.
        rot = np.array(
            [[1.0, 0.0, 0.0], [0.0, math.cos(th), math.sin(th)], [0.0, math.sin(th), -math.cos(th)]]
        )
        cam_pos = np.array([cx, cy, 0.0]) - d * rot[2]
        ground = np.array(
            [[1.0, 0.0, -cam_pos[0]], [0.0, 1.0, -cam_pos[1]], [0.0, 0.0, -cam_pos[2]]]
        )
        f = s * d  # focal length (px) giving scale s at the look-at point
        k = np.array([[f, 0.0, u0], [0.0, f, v0], [0.0, 0.0, 1.0]])
        h = k @ rot @ ground
        return h / h[2, 2]

    def jitter(self, n_frames: int) -> np.ndarray:
        """``(n_frames, 2)`` pixel offsets added to every projected point of a frame.

        A seeded AR(1) process with stationary standard deviation ``jitter_px`` and correlation
        time ``jitter_frames`` (zeros when ``jitter_px == 0``), plus one such process per shake
        burst (:attr:`shake_events`), of the burst's own standard deviation, on its frames
        only. Frame ``t``'s offset does not depend on ``n_frames``.
        """
        if n_frames < 0:
            raise ValueError(f"n_frames must be >= 0, got {n_frames}")
        out = np.zeros((n_frames, 2))
        if n_frames == 0:
            return out
        if self.jitter_px > 0.0:
            out += self._ar1(n_frames, self.jitter_px, [self.seed, 0x4A17])
        for i, ev in zip(self._burst_keys(), self.shake_events, strict=True):
            if ev.magnitude > 0.0:
                burst = self._ar1(n_frames, ev.magnitude, [self.seed, 0x5B0057, i])
                out += burst * ev.mask(n_frames)[:, None]
        return out

    def _burst_keys(self) -> list[int]:
        """Each shake burst's seed key: its place among the spec's shake bursts
        (:attr:`Event.ordinal`), so a burst stays the same when ``--frames`` drops bursts that
        start after the cut; bursts built by hand without distinct places take their order
        (the same keys for a spec's whole list)."""
        keys = [ev.ordinal for ev in self.shake_events]
        return keys if len(set(keys)) == len(keys) else list(range(len(keys)))

    def _ar1(self, n_frames: int, sigma: float, seed: list[int]) -> np.ndarray:
        """``(n_frames, 2)`` seeded AR(1) offsets of stationary deviation ``sigma`` and
        correlation time ``jitter_frames``; frame ``t``'s offset does not depend on
        ``n_frames`` (drawn in frame order)."""
        out = np.zeros((n_frames, 2))
        rng = np.random.default_rng(np.random.SeedSequence(seed))
        a = math.exp(-1.0 / self.jitter_frames)
        out[0] = rng.standard_normal(2) * sigma
        innov = rng.standard_normal((n_frames, 2)) * sigma * math.sqrt(1.0 - a * a)
        for t in range(1, n_frames):
            out[t] = a * out[t - 1] + innov[t]
        return out

    @property
    def shake_px(self) -> float:
        """The largest shake deviation on any frame (``jitter_px`` plus the bursts)."""
        return self.jitter_px + sum(e.magnitude for e in self.shake_events)

    @property
    def ground_margin(self) -> int:
        """Ground, px, the renderer draws beyond each side of the frame: what the shake needs
        (:func:`shake_margin`), or ``ground_margin_px`` if that is more."""
        return max(shake_margin(self.shake_px), self.ground_margin_px)

    @property
    def drone_on(self) -> bool:
        """Whether the drone profile moves the view (any of drift, rotation, zoom)."""
        return self.drift_px > 0 or self.rotate_deg > 0 or self.zoom > 0

    @property
    def moves(self) -> bool:
        """Whether the image moves over the ground at all (shake or drone profile)."""
        return self.shake_px > 0 or self.drone_on

    def drone(self, n_frames: int) -> np.ndarray:
        """``(n_frames, 2, 3)`` affine maps of the drone profile, from the shaken image to the
        one seen: ``q = c + d_t + z_t R(theta_t) (p - c)`` about the frame centre ``c``.

        Drift ``d_t`` (each axis within ``drift_px``), rotation ``theta_t`` (within
        ``rotate_deg``) and zoom ``z_t`` (within ``1 +- zoom``) are each a weighted sum of three
        seeded sinusoids with periods of 0.5-1.5 ``drone_frames``: smooth, bounded, and frame
        ``t``'s map does not depend on ``n_frames``. The identity when the profile is off.
        """
        if n_frames < 0:
            raise ValueError(f"n_frames must be >= 0, got {n_frames}")
        out = np.zeros((n_frames, 2, 3))
        out[:, 0, 0] = out[:, 1, 1] = 1.0
        if not self.drone_on or n_frames == 0:
            return out
        rng = np.random.default_rng(np.random.SeedSequence([self.seed, 0xD209E]))
        periods = self.drone_frames * rng.uniform(0.5, 1.5, (4, 3))
        phases = rng.uniform(0.0, 2 * math.pi, (4, 3))
        weights = rng.uniform(0.5, 1.0, (4, 3))
        weights /= weights.sum(axis=1, keepdims=True)
        t = np.arange(n_frames, dtype=np.float64)[:, None, None]
        wave = (weights * np.sin(2 * math.pi * t / periods + phases)).sum(axis=2)  # (T, 4)
        dx, dy = self.drift_px * wave[:, 0], self.drift_px * wave[:, 1]
        theta = np.radians(self.rotate_deg) * wave[:, 2]
        z = 1.0 + self.zoom * wave[:, 3]
        c = np.array([self.width / 2.0, self.height / 2.0])
        lin = np.empty((n_frames, 2, 2))
        lin[:, 0, 0] = lin[:, 1, 1] = z * np.cos(theta)
        lin[:, 0, 1] = -z * np.sin(theta)
        lin[:, 1, 0] = z * np.sin(theta)
        out[:, :, :2] = lin
        out[:, :, 2] = c + np.stack([dx, dy], axis=1) - lin @ c
        return out

    def frame_motion(self, n_frames: int) -> np.ndarray:
        """``(n_frames - 1, 2, 3)``: for ``t = 1 ..``, the map from frame ``t - 1``'s pixels
        to frame ``t``'s that this camera makes: undo the drone view of ``t - 1``
        (:meth:`drone`), move by the shake's step (:meth:`jitter`), apply the drone view of
        ``t``. Without the drone profile, exactly the shift ``jitter[t] - jitter[t - 1]``.
        What a camera-motion estimate should find (``benchmarks/cmc_error.py``).

        >>> cam = Camera(px_per_m=10.0, width=64, height=48, jitter_px=2.0, seed=1)
        >>> m = cam.frame_motion(5)
        >>> m.shape, bool((m[:, :, 2] == np.diff(cam.jitter(5), axis=0)).all())
        ((4, 2, 3), True)
        """
        jitter = self.jitter(n_frames)
        steps = np.diff(jitter, axis=0)
        out = np.zeros((len(steps), 2, 3))
        out[:, 0, 0] = out[:, 1, 1] = 1.0
        out[:, :, 2] = steps
        if not self.drone_on:
            return out
        views = np.zeros((n_frames, 3, 3))
        views[:, :2] = self.drone(n_frames)
        views[:, 2, 2] = 1.0
        shift = np.zeros((len(steps), 3, 3))
        shift[:, :2] = out
        shift[:, 2, 2] = 1.0
        return (views[1:] @ shift @ np.linalg.inv(views[:-1]))[:, :2]

    def _canvas_margins(self) -> tuple[int, int]:
        half_w, half_h = self.width / 2.0, self.height / 2.0
        sin = math.sin(math.radians(self.rotate_deg))
        z_min = 1.0 - self.zoom
        reach_x = ((half_w + self.drift_px) + (half_h + self.drift_px) * sin) / z_min
        reach_y = ((half_h + self.drift_px) + (half_w + self.drift_px) * sin) / z_min
        # +2: the bilinear warp's neighbours
        return int(math.ceil(reach_x - half_w)) + 2, int(math.ceil(reach_y - half_h)) + 2

    def canvas(self) -> tuple[Camera, tuple[int, int]]:
        """``(camera, (mx, my))``: the larger, drone-free camera the renderer draws before the
        drone profile's warp, and its margins. It sees the same ground (same centre, scale,
        tilt and shake) offset by ``(mx, my)`` pixels, with margins large enough that every
        pixel of every view comes from inside it. ``(self, (0, 0))`` when the profile is off.
        """
        if not self.drone_on:
            return self, (0, 0)
        mx, my = self._canvas_margins()
        big = replace(
            self,
            width=self.width + 2 * mx,
            height=self.height + 2 * my,
            drift_px=0.0,
            rotate_deg=0.0,
            zoom=0.0,
        )
        return big, (mx, my)

    def project(self, points: np.ndarray) -> np.ndarray:
        """Map ``(..., 2)`` metres to ``(..., 2)`` pixels (NaN stays NaN; no jitter)."""
        pts = np.asarray(points, dtype=np.float64)
        h = self.homography
        x, y = pts[..., 0], pts[..., 1]
        w = h[2, 0] * x + h[2, 1] * y + h[2, 2]
        u = (h[0, 0] * x + h[0, 1] * y + h[0, 2]) / w
        v = (h[1, 0] * x + h[1, 1] * y + h[1, 2]) / w
        return np.stack([u, v], axis=-1)

    def unproject(self, pixels: np.ndarray) -> np.ndarray:
        """Inverse of :meth:`project`: ``(..., 2)`` pixels to ``(..., 2)`` metres."""
        px = np.asarray(pixels, dtype=np.float64)
        h = np.linalg.inv(self.homography)
        u, v = px[..., 0], px[..., 1]
        w = h[2, 0] * u + h[2, 1] * v + h[2, 2]
        return np.stack(
            [(h[0, 0] * u + h[0, 1] * v + h[0, 2]) / w, (h[1, 0] * u + h[1, 1] * v + h[1, 2]) / w],
            axis=-1,
        )

    def project_trajectories(self, positions: np.ndarray) -> np.ndarray:
        """``(T, N, 2)`` metres -> ``(T, N, 2)`` pixels including the per-frame jitter and the
        drone profile's view (:meth:`drone`)."""
        pos = np.asarray(positions, dtype=np.float64)
        if pos.ndim != 3 or pos.shape[2] != 2:
            raise ValueError(f"positions must have shape (T, N, 2), got {pos.shape}")
        px = self.project(pos) + self.jitter(pos.shape[0])[:, None, :]
        if self.drone_on:
            m = self.drone(pos.shape[0])
            px = np.einsum("tij,tnj->tni", m[:, :, :2], px) + m[:, None, :, 2]
        return px

    def scale_at(self, points: np.ndarray) -> np.ndarray:
        """``(...)`` local scale in px/m at ground ``points`` (``px_per_m`` when untilted)."""
        pts = np.asarray(points, dtype=np.float64)
        eps = 0.05
        a = self.project(pts)
        b = self.project(pts + np.array([eps, 0.0]))
        return np.linalg.norm(b - a, axis=-1) / eps

    def visible(self, pixels: np.ndarray, margin: float = 0.0) -> np.ndarray:
        """``(...)`` bool: pixel points inside the frame shrunk by ``margin`` (NaN -> False)."""
        px = np.asarray(pixels, dtype=np.float64)
        u, v = px[..., 0], px[..., 1]
        with np.errstate(invalid="ignore"):
            return (
                (u >= margin)
                & (u <= self.width - 1 - margin)
                & (v >= margin)
                & (v <= self.height - 1 - margin)
            )
