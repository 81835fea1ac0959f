"""How people and the scene look from above: parameters, palettes and the sprite bank.

People are small (a template of 8–16 px, SPEC §4): a head disc, with a skin-coloured face
crescent on the walking side, over a shoulder ellipse turned across the walking direction.
Clothing colours come from a few dense colour clusters (most people look alike); a fraction
of people, the "prominent" ones, wear distinct colours.

Every combination ``(appearance, orientation bin, sub-pixel phase)`` is drawn once, anti-aliased
by supersampling, into a :class:`SpriteBank`; the renderer then only stamps sprites. Sprite
geometry: a sprite is ``Z x Z`` pixels with ``Z = template_px + 2``; for sub-pixel phase
``(py, px)`` the head centre lies at ``((Z - 1) / 2 + py / P, (Z - 1) / 2 + px / P)`` inside the
sprite, where ``P = subpixel``.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields

import cv2
import numpy as np

from crowdsim.checks import require_choice, require_number

PALETTES: dict[str, tuple[tuple[int, int, int], ...]] = {
    # BGR clothing cluster centres.
    "dull": ((60, 50, 45), (40, 40, 40), (120, 110, 100), (90, 70, 50), (150, 150, 150)),
    "white": ((235, 235, 235), (215, 220, 222), (200, 205, 205), (60, 60, 60)),
    "sport": ((60, 60, 200), (200, 120, 40), (230, 230, 230), (40, 40, 40), (60, 170, 60)),
    "dark": ((45, 45, 45), (60, 55, 50), (75, 70, 70), (55, 60, 70)),
}
"""Named clothing palettes: each a tuple of BGR cluster centres (the first is the densest)."""

PROMINENT_COLOURS: tuple[tuple[int, int, int], ...] = (
    (0, 0, 230), (0, 220, 255), (230, 60, 0), (0, 200, 0), (200, 0, 200), (255, 255, 0),
    (0, 128, 255), (128, 0, 255), (255, 128, 128), (0, 255, 128), (30, 90, 160), (180, 255, 180),
)
"""BGR colours of prominent people ("queens"), far from every palette cluster."""

HAIR_COLOURS: tuple[tuple[int, int, int], ...] = ((20, 20, 25), (25, 40, 60), (40, 70, 110),
                                                   (150, 150, 160))
SKIN_COLOURS: tuple[tuple[int, int, int], ...] = ((140, 170, 215), (90, 130, 180), (60, 85, 120))
SUPERSAMPLE: int = 8
"""Drawing resolution factor used to anti-alias the sprites."""
SHOULDER_DEPTH: float = 0.28
"""Half depth of the shoulder ellipse as a fraction of the template size."""
HEAD_RADIUS: float = 0.21
"""Head radius as a fraction of the template size."""
SHADOW_OFFSET: tuple[float, float] = (0.3, 0.21)
"""Shadow centre offset from the head centre (u, v), fraction of the template (sun upper left)."""
SHADOW_REACH: float = 0.55
"""Padding of the sprites around the template for the shadow, fraction of the template."""
SHADOW_BLUR: float = 0.08
"""Shadow edge blur (Gaussian sigma), fraction of the template."""
ALPHA_EPS: float = 0.004
"""Coverage below this is treated as empty (not composited)."""
FACE_OFFSET: float = 0.14
"""Distance of the face crescent's centre ahead of the head centre, fraction of the template."""


@dataclass(frozen=True)
class AppearanceParams:
    """Appearance and image-noise knobs of one sequence (the calibration knobs of SPEC §4).

    Attributes
    ----------
    template_px : int
        Template (sprite) size in pixels: shoulder width; the ground-truth box side.
    palette : str
        Clothing palette name, see :data:`PALETTES`.
    n_clusters : int
        How many palette clusters are used (the first ones; cluster k has weight ~ 0.5^k).
    variants_per_cluster : int
        Colour variants drawn around each cluster centre.
    cluster_spread : float
        Standard deviation (grey levels) of the variants around their cluster centre.
    prominent_fraction : float
        Fraction of people drawn with a distinct colour when the trajectories carry no
        ``prominent`` attribute.
    contrast : float
        Scales the clothing colours' difference from the ground colour (``< 1`` = people
        blend into the ground, as in low-contrast outdoor scenes).
    ground_bgr : (int, int, int)
        Mean ground colour.
    ground_texture : float
        Standard deviation (grey levels) of the ground texture.
    paving_m : float
        Paving slab size in metres (0 = no slabs).
    shadow : float
        Darkening of the ground under a shadow, in [0, 1].
    sway_deg : float
        Amplitude of the shoulder sway around the walking direction, degrees.
    illumination_drift : float
        Relative amplitude of the slow global illumination change.
    illumination_period_s : float
        Period of the illumination change, seconds.
    noise_sigma : float
        Sensor noise standard deviation, grey levels.
    jpeg_quality : int
        JPEG quality of the written frames (1–100).
    motion_blur_px : float
        Length of a horizontal-ish camera motion blur kernel, pixels (0 = off).
    orientation_bins : int
        Number of orientation bins of the sprite bank.
    subpixel : int
        Sub-pixel phases per axis of the sprite bank.
    """

    template_px: int = 12
    palette: str = "dull"
    n_clusters: int = 3
    variants_per_cluster: int = 4
    cluster_spread: float = 10.0
    prominent_fraction: float = 0.05
    contrast: float = 1.0
    ground_bgr: tuple[int, int, int] = (115, 125, 130)
    ground_texture: float = 10.0
    paving_m: float = 0.0
    shadow: float = 0.35
    sway_deg: float = 8.0
    illumination_drift: float = 0.06
    illumination_period_s: float = 30.0
    noise_sigma: float = 3.0
    jpeg_quality: int = 90
    motion_blur_px: float = 0.0
    orientation_bins: int = 32
    subpixel: int = 2

    def __post_init__(self) -> None:
        own = "appearance"
        require_choice(own, "palette", self.palette, tuple(sorted(PALETTES)))
        for name, lo, hi in (("template_px", 4, 64), ("n_clusters", 1, len(PALETTES[self.palette])),
                             ("variants_per_cluster", 1, 16), ("jpeg_quality", 1, 100),
                             ("orientation_bins", 4, 128), ("subpixel", 1, 4)):
            require_number(own, name, getattr(self, name), lo=lo, hi=hi, integer=True)
        for name, lo, hi in (("cluster_spread", 0, 100), ("prominent_fraction", 0, 1),
                             ("contrast", 0.05, 2), ("ground_texture", 0, 80),
                             ("paving_m", 0, 100), ("shadow", 0, 1), ("sway_deg", 0, 45),
                             ("illumination_drift", 0, 0.5), ("noise_sigma", 0, 50),
                             ("motion_blur_px", 0, 30)):
            require_number(own, name, getattr(self, name), lo=lo, hi=hi)
        require_number(own, "illumination_period_s", self.illumination_period_s, lo=0,
                       lo_open=True)
        if len(self.ground_bgr) != 3:
            raise ValueError(f"appearance.ground_bgr must be three numbers in [0, 255], "
                             f"got {self.ground_bgr!r}")
        for c in self.ground_bgr:
            require_number(own, "ground_bgr", c, lo=0, hi=255)
        object.__setattr__(self, "ground_bgr", tuple(int(c) for c in self.ground_bgr))

    @classmethod
    def from_dict(cls, values: dict) -> AppearanceParams:
        """Build from a mapping, rejecting unknown keys by name."""
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(values) - known)
        if unknown:
            raise ValueError(f"appearance: unknown field {unknown[0]!r}")
        kw = dict(values)
        if "ground_bgr" in kw:
            kw["ground_bgr"] = tuple(kw["ground_bgr"])
        return cls(**kw)

    def to_dict(self) -> dict:
        d = asdict(self)
        d["ground_bgr"] = list(self.ground_bgr)
        return d

    @property
    def n_appearances(self) -> int:
        """Number of distinct looks: palette variants plus prominent colours."""
        return self.n_clusters * self.variants_per_cluster + len(PROMINENT_COLOURS)


@dataclass(frozen=True)
class SpriteBank:
    """Pre-rendered people with their shadows baked in.

    Sprite ``k = index(a, b, py, px)`` is appearance ``a`` facing orientation bin ``b`` with
    sub-pixel phase ``(py, px)``; its head centre lies at
    ``((Z - 1) / 2 + py / P, (Z - 1) / 2 + px / P)`` inside the ``Z x Z`` sprite.

    Attributes
    ----------
    color : (K, Z, Z, 3) float32
        Premultiplied BGR (grey levels times coverage).
    alpha : (K, Z, Z) float32
        Coverage in [0, 1]; a shadow is a black, partly transparent part of the sprite.
    spans : (K, Z, 2) int32
        Per sprite row, the half-open column range ``[lo, hi)`` where alpha is not negligible
        (``lo == hi`` for an empty row); lets the compositing loop skip empty pixels.
    n_bins, subpixel, size : int
        ``B``, ``P`` and ``Z``.
    """

    color: np.ndarray
    alpha: np.ndarray
    spans: np.ndarray
    n_bins: int
    subpixel: int
    size: int

    def index(self, appearance: np.ndarray, bins: np.ndarray, py: np.ndarray,
              px: np.ndarray) -> np.ndarray:
        """Flat sprite index of ``(appearance, orientation bin, phase y, phase x)`` arrays."""
        p = self.subpixel
        return ((appearance * self.n_bins + bins) * p + py) * p + px


def appearance_colours(params: AppearanceParams, rng: np.random.Generator) -> np.ndarray:
    """``(A, 3)`` float BGR clothing colours: cluster variants first, then prominent colours."""
    ground = np.array(params.ground_bgr, dtype=np.float64)
    out = []
    for k in range(params.n_clusters):
        centre = np.array(PALETTES[params.palette][k], dtype=np.float64)
        for _ in range(params.variants_per_cluster):
            out.append(centre + rng.normal(0.0, params.cluster_spread, 3))
    out.extend(np.array(PROMINENT_COLOURS, dtype=np.float64))
    colours = np.array(out)
    colours = ground + params.contrast * (colours - ground)
    return np.clip(colours, 0, 255)


def cluster_weights(params: AppearanceParams) -> np.ndarray:
    """``(n_clusters,)`` probabilities of the clothing clusters (dense first cluster)."""
    w = 0.5 ** np.arange(params.n_clusters)
    return w / w.sum()


def _draw_person(size_hi: int, centre: float, scale: float, angle: float, cloth: np.ndarray,
                 hair: np.ndarray, skin: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Draw one person at supersampled resolution; returns (premultiplied bgr, alpha)."""
    shift = 4
    one = 1 << shift
    img = np.zeros((size_hi, size_hi, 3), np.float32)
    mask = np.zeros((size_hi, size_hi), np.float32)
    c = (int(round(centre * one)), int(round(centre * one)))
    deg = math.degrees(angle)
    # Shoulders: long axis across the walking direction, slightly behind the head.
    back = 0.05 * scale
    sc = (int(round((centre - back * math.cos(angle)) * one)),
          int(round((centre - back * math.sin(angle)) * one)))
    axes = (int(round(SHOULDER_DEPTH * scale * one)), int(round(0.49 * scale * one)))
    cv2.ellipse(img, sc, axes, deg, 0, 360, tuple(float(v) for v in cloth), -1, cv2.LINE_AA, shift)
    cv2.ellipse(mask, sc, axes, deg, 0, 360, 1.0, -1, cv2.LINE_AA, shift)
    r = int(round(HEAD_RADIUS * scale * one))
    cv2.circle(img, c, r, tuple(float(v) for v in hair), -1, cv2.LINE_AA, shift)
    cv2.circle(mask, c, r, 1.0, -1, cv2.LINE_AA, shift)
    # Face: a skin crescent on the walking side of the head.
    # From above mostly hair is seen; the face is a thin crescent at the front of the head,
    # so the head centre (the ground-truth point) stays hair-coloured.
    fwd = FACE_OFFSET * scale
    fc = (int(round((centre + fwd * math.cos(angle)) * one)),
          int(round((centre + fwd * math.sin(angle)) * one)))
    face_axes = (int(round(0.07 * scale * one)), int(round(0.13 * scale * one)))
    cv2.ellipse(img, fc, face_axes, deg, 0, 360, tuple(float(v) for v in skin), -1, cv2.LINE_AA,
                shift)
    return img, mask


def _shadow_hi(size_hi: int, centre: float, scale: float, angle: float,
               blur_hi: float) -> np.ndarray:
    """Soft shadow coverage at supersampled resolution, offset towards the lower right."""
    hi = np.zeros((size_hi, size_hi), np.float32)
    one = 16
    cx = centre + SHADOW_OFFSET[0] * scale
    cy = centre + SHADOW_OFFSET[1] * scale
    cv2.ellipse(hi, (int(round(cx * one)), int(round(cy * one))),
                (int(round(0.33 * scale * one)), int(round(0.5 * scale * one))),
                math.degrees(angle), 0, 360, 1.0, -1, cv2.LINE_AA, 4)
    return cv2.GaussianBlur(hi, (0, 0), blur_hi)


def build_sprite_bank(params: AppearanceParams, rng: np.random.Generator) -> SpriteBank:
    """Render every ``(appearance, orientation, sub-pixel phase)`` sprite, shadow included.

    Orientation bin ``b`` faces the image direction ``angle = 2 pi b / B`` (``u`` right,
    ``v`` down).
    """
    s = params.template_px
    pad = int(math.ceil(SHADOW_REACH * s)) + 1 if params.shadow > 0 else 0
    z = s + 2 + 2 * pad
    p = params.subpixel
    ss = SUPERSAMPLE
    if ss % p:
        raise ValueError(f"appearance.subpixel must divide {ss}, got {p}")
    step = ss // p
    n_app = params.n_appearances
    nb = params.orientation_bins
    colours = appearance_colours(params, rng)
    hair = np.array(HAIR_COLOURS, np.float64)[rng.integers(0, len(HAIR_COLOURS), n_app)]
    skin = np.array(SKIN_COLOURS, np.float64)[rng.integers(0, len(SKIN_COLOURS), n_app)]
    ground = np.array(params.ground_bgr, np.float64)
    hair = ground + params.contrast * (hair - ground)
    skin = ground + params.contrast * (skin - ground)
    size_hi = z * ss
    pad_hi = ss  # one low-res pixel of room for the sub-pixel shifts
    # Hi-res coordinate of the low-res pixel centre (Z - 1) / 2, inside the padded canvas.
    centre_hi = ((z - 1) / 2.0 + 0.5) * ss - 0.5 + pad_hi
    color = np.zeros((n_app, nb, p, p, z, z, 3), np.float32)
    alpha = np.zeros((n_app, nb, p, p, z, z), np.float32)
    for b in range(nb):
        angle = 2.0 * math.pi * b / nb
        shadow = None
        if params.shadow > 0:
            shadow = params.shadow * _shadow_hi(size_hi + 2 * pad_hi, centre_hi, s * ss, angle,
                                                max(0.6, SHADOW_BLUR * s) * ss)
        for a in range(n_app):
            # Anti-aliased drawing over black is already premultiplied by the coverage.
            img, mask = _draw_person(size_hi + 2 * pad_hi, centre_hi, s * ss, angle,
                                     colours[a], hair[a], skin[a])
            if shadow is not None:  # person over a black, partly transparent shadow
                mask = mask + shadow * (1.0 - mask)
            for py in range(p):
                for px in range(p):
                    # Shift the drawing by (py, px) / P low-res pixels = step * (py, px) hi-res.
                    y0 = pad_hi - py * step
                    x0 = pad_hi - px * step
                    color[a, b, py, px] = cv2.resize(img[y0:y0 + size_hi, x0:x0 + size_hi],
                                                     (z, z), interpolation=cv2.INTER_AREA)
                    alpha[a, b, py, px] = cv2.resize(mask[y0:y0 + size_hi, x0:x0 + size_hi],
                                                     (z, z), interpolation=cv2.INTER_AREA)
    alpha = alpha.reshape(-1, z, z)
    visible = alpha > ALPHA_EPS
    any_row = visible.any(axis=2)
    lo = np.where(any_row, np.argmax(visible, axis=2), 0)
    hi = np.where(any_row, z - np.argmax(visible[:, :, ::-1], axis=2), 0)
    alpha[~visible] = 0.0
    color = color.reshape(-1, z, z, 3)
    color[~visible] = 0.0
    return SpriteBank(color=color, alpha=alpha, spans=np.stack([lo, hi], -1).astype(np.int32),
                      n_bins=nb, subpixel=p, size=z)
