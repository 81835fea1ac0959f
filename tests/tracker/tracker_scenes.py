"""Tiny hand-built scenes with exact ground truth for tracker tests.

Coloured square "heads" of ``size`` px move at integer velocities over a seeded random
texture; positions are integer pixels, so a correct tracker recovers them exactly.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

PALETTE = np.array([[255, 40, 40], [40, 220, 255], [40, 40, 230], [40, 230, 40],
                    [230, 40, 230], [240, 240, 40], [200, 200, 200], [20, 120, 250]],
                   dtype=np.uint8)


@dataclass
class Scene:
    frames: list[np.ndarray]
    ids: np.ndarray
    points: np.ndarray  # (T, N, 2) float, NaN where absent
    template_size: int


def make_scene(starts, velocities, n_frames: int = 12, shape=(96, 128), size: int = 8,
               seed: int = 0, colours=None, birth_frames=None) -> Scene:
    """Two-tone blobs of ``size - 2`` px (dark 2x2 centre) at ``start + t * velocity`` (px)."""
    rng = np.random.default_rng(seed)
    starts = np.asarray(starts, dtype=np.int64).reshape(-1, 2)
    vel = np.asarray(velocities, dtype=np.int64).reshape(-1, 2)
    n = len(starts)
    h, w = shape
    bg = rng.integers(70, 130, (h, w, 3)).astype(np.uint8)
    cols = PALETTE[np.arange(n) % len(PALETTE)] if colours is None else np.asarray(colours)
    birth = np.zeros(n, np.int64) if birth_frames is None else np.asarray(birth_frames)
    pts = np.full((n_frames, n, 2), np.nan)
    frames = []
    half = (size - 2) // 2
    for t in range(n_frames):
        f = bg.copy()
        for i in range(n):
            if t < birth[i]:
                continue
            x, y = starts[i] + (t - birth[i]) * vel[i]
            if not (0 <= x < w and 0 <= y < h):
                continue
            pts[t, i] = (x, y)
            f[max(0, y - half):y + half + 1, max(0, x - half):x + half + 1] = cols[i]
            # a dark "head" in the middle so that no template is flat (NCC needs variance)
            f[max(0, y - 1):y + 1, max(0, x - 1):x + 1] = cols[i] // 4
        frames.append(f)
    return Scene(frames, np.arange(1, n + 1), pts, size)
