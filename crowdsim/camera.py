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

Examples
--------
>>> cam = Camera(px_per_m=10.0, width=200, height=100, center=(0.0, 0.0))
>>> cam.project(np.array([[0.0, 0.0], [1.0, 2.0]])).round(3).tolist()
[[100.0, 50.0], [110.0, 70.0]]
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from crowdsim.knobs import knob

JITTER_CORRELATION_FRAMES: float = knob("jitter_frames").default
"""Default time constant (frames) of the camera shake: an AR(1) process with this correlation
time (``Camera.jitter_frames``)."""


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
        Seed of the jitter process.
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

    def __post_init__(self) -> None:
        if not (math.isfinite(self.px_per_m) and self.px_per_m > 0):
            raise ValueError(f"camera.px_per_m must be > 0, got {self.px_per_m!r}")
        for name in ("width", "height"):
            value = getattr(self, name)
            if not isinstance(value, (int, np.integer)) or value < 8 or value > 16384:
                raise ValueError(f"camera.{name} must be an integer in [8, 16384], got {value!r}")
        if not (0.0 <= self.tilt_deg < 60.0):
            raise ValueError(f"camera.tilt_deg must be in [0, 60), got {self.tilt_deg!r}")
        if not (math.isfinite(self.distance_m) and self.distance_m > 0):
            raise ValueError(f"camera.distance_m must be > 0, got {self.distance_m!r}")
        for name in ("jitter_px", "jitter_frames"):  # the shake knobs: ranges in crowdsim.knobs
            knob(name).check("camera", getattr(self, name))
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
        max_size: tuple[int, int] = (1920, 1080),
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
        time ``jitter_frames`` (zeros when ``jitter_px == 0``). Frame ``t``'s offset does not
        depend on ``n_frames``.
        """
        if n_frames < 0:
            raise ValueError(f"n_frames must be >= 0, got {n_frames}")
        out = np.zeros((n_frames, 2))
        if self.jitter_px == 0.0 or n_frames == 0:
            return out
        rng = np.random.default_rng(np.random.SeedSequence([self.seed, 0x4A17]))
        a = math.exp(-1.0 / self.jitter_frames)
        # Draw in frame order so that frame t's offset does not depend on n_frames.
        out[0] = rng.standard_normal(2) * self.jitter_px
        innov = rng.standard_normal((n_frames, 2)) * self.jitter_px * math.sqrt(1.0 - a * a)
        for t in range(1, n_frames):
            out[t] = a * out[t - 1] + innov[t]
        return out

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
        """``(T, N, 2)`` metres -> ``(T, N, 2)`` pixels including the per-frame jitter."""
        pos = np.asarray(positions, dtype=np.float64)
        if pos.ndim != 3 or pos.shape[2] != 2:
            raise ValueError(f"positions must have shape (T, N, 2), got {pos.shape}")
        return self.project(pos) + self.jitter(pos.shape[0])[:, None, :]

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
