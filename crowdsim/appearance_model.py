"""How people and the scene look from above: parameters, palettes and the sprite bank.

People are small (a template of 8–16 px, SPEC §4): a head disc, with a skin-coloured face
crescent on the walking side, over a shoulder ellipse turned across the walking direction.
Clothing colours come from a few dense colour clusters (most people look alike); a fraction
of people, the "prominent" ones, wear distinct colours.

Every combination ``(pose, orientation bin, sub-pixel phase)`` is drawn once, anti-aliased by
supersampling, into a :class:`SpriteBank` of *coverages*: per pixel, the visible coverage of the
clothing, the hair and the face, the total coverage (shadow included), the solid (person)
coverage and the head disc. A person's colour is linear in these coverages (anti-aliased
drawing over black is), so one geometry serves every appearance: the renderer mixes the three
colours of an appearance with the coverages while it stamps. A pose is a gait phase (arm swing,
body bob) and a head turn; there is one pose unless those knobs are on. Sprite geometry: a
sprite is ``Z x Z`` pixels; for sub-pixel phase ``(py, px)`` the head centre lies at
``((Z - 1) / 2 + py / P, (Z - 1) / 2 + px / P)`` inside the sprite, where ``P = subpixel``.

Realistic-difficulty knobs (issue 8) all default to off or to the earlier look, so specs that
do not set them render as before: look-alike heads (``dark_hair_fraction``, ``hair_spread``),
tight clothing clusters (``cluster_spread``, ``cluster_decay``), packing (``body_scale``),
occlusion order (``heads_on_top``),
appearance change over time (``arm_swing``, ``gait_bob``, ``head_turn_deg``), clutter
(``distractor_density``, ``moving_shadow_density``) and the camera's image formation
(``defocus_px``, ``flicker``, ``video_kbps``, ``video_codec``).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields

import cv2
import numpy as np

from crowdsim.checks import require_number
from crowdsim.knobs import ENCODING, attributes_doc, defaults, knob, knobs

PALETTES: dict[str, tuple[tuple[int, int, int], ...]] = {
    # BGR clothing cluster centres.
    "dull": ((60, 50, 45), (40, 40, 40), (120, 110, 100), (90, 70, 50), (150, 150, 150)),
    "white": ((235, 235, 235), (215, 220, 222), (200, 205, 205), (60, 60, 60)),
    "sport": ((60, 60, 200), (200, 120, 40), (230, 230, 230), (40, 40, 40), (60, 170, 60)),
    "dark": ((45, 45, 45), (60, 55, 50), (75, 70, 70), (55, 60, 70)),
}
"""Named clothing palettes: each a tuple of BGR cluster centres (the first is the densest)."""

PROMINENT_COLOURS: tuple[tuple[int, int, int], ...] = (
    (0, 0, 230),
    (0, 220, 255),
    (230, 60, 0),
    (0, 200, 0),
    (200, 0, 200),
    (255, 255, 0),
    (0, 128, 255),
    (128, 0, 255),
    (255, 128, 128),
    (0, 255, 128),
    (30, 90, 160),
    (180, 255, 180),
)
"""BGR colours of prominent people ("queens"), far from every palette cluster."""

HAIR_COLOURS: tuple[tuple[int, int, int], ...] = (
    (20, 20, 25),
    (25, 40, 60),
    (40, 70, 110),
    (150, 150, 160),
)
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
SHOULDER_HALF_WIDTH: float = 0.49
"""Half width of the shoulder ellipse (across the walking direction), fraction of the template."""
GAIT_PHASES: int = 4
"""Gait phases drawn when ``arm_swing`` or ``gait_bob`` is on (0, 90, 180, 270 degrees)."""
HEAD_TURNS: int = 3
"""Head-turn poses drawn when ``head_turn_deg`` is on (left, straight, right)."""
ARM_OFFSET: float = 0.40
"""Distance of an arm's centre from the body axis, fraction of the template (times body_scale)."""
ARM_AXES: tuple[float, float] = (0.17, 0.08)
"""Half length (along the walking direction) and half width of an arm, fraction of template."""
SOLID_COVERAGE: float = 0.5
"""A person owns a pixel (for occlusion and visibility) where its coverage is at least this."""
VIDEO_CODECS: tuple[str, ...] = knob("video_codec").choices
"""Codecs of ``video_kbps``: H.264 (libx264 through PyAV) and MPEG-4 part 2 (mp4v)."""


_D = defaults("appearance")


@dataclass(frozen=True)
class Encoding:
    """How the camera's output is encoded: the one parameter set of the output-encoding step.

    The rendered frames pass through the video codec (when ``video_kbps > 0``) and then JPEG,
    in that order, both in ``generate``'s writer and in in-memory episodes
    (:func:`synth_data.video.encode_output`, the one code path). The ranges are the
    :mod:`crowdsim.knobs` rows of the same names.

    Attributes
    ----------
    jpeg_quality : int
        JPEG quality, 1-100.
    video_kbps : float
        Codec bit rate, kbit/s; 0 = no codec.
    video_codec : str
        ``"h264"`` or ``"mpeg4"``.
    """

    jpeg_quality: int = _D["jpeg_quality"]
    video_kbps: float = _D["video_kbps"]
    video_codec: str = _D["video_codec"]

    def __post_init__(self) -> None:
        for name in ENCODING:
            knob(name).check("appearance", getattr(self, name))


@dataclass(frozen=True)
class AppearanceParams:
    """Appearance and image-formation knobs of one sequence (the ``[appearance]`` of a spec).

    One field per ``appearance`` row of :data:`crowdsim.knobs.KNOBS`, which holds each field's
    default, range, difficulty scale and meaning (listed below from that table). Every knob added
    for realistic difficulty defaults to off or to the earlier look, so a spec that does not set
    it renders exactly as before; the calibration turns them on per sequence. Validation reads
    the same table: a value out of range raises ``ValueError`` naming ``appearance.<field>``.

    Attributes
    ----------
    """

    template_px: int = _D["template_px"]
    palette: str = _D["palette"]
    n_clusters: int = _D["n_clusters"]
    variants_per_cluster: int = _D["variants_per_cluster"]
    cluster_spread: float = _D["cluster_spread"]
    cluster_decay: float = _D["cluster_decay"]
    prominent_fraction: float = _D["prominent_fraction"]
    dark_hair_fraction: float = _D["dark_hair_fraction"]
    hair_spread: float = _D["hair_spread"]
    contrast: float = _D["contrast"]
    body_scale: float = _D["body_scale"]
    heads_on_top: bool = _D["heads_on_top"]
    ground_bgr: tuple[int, int, int] = _D["ground_bgr"]
    ground_texture: float = _D["ground_texture"]
    paving_m: float = _D["paving_m"]
    shadow: float = _D["shadow"]
    sway_deg: float = _D["sway_deg"]
    arm_swing: float = _D["arm_swing"]
    gait_bob: float = _D["gait_bob"]
    head_turn_deg: float = _D["head_turn_deg"]
    head_turn_period_s: float = _D["head_turn_period_s"]
    distractor_density: float = _D["distractor_density"]
    moving_shadow_density: float = _D["moving_shadow_density"]
    moving_shadow_m: float = _D["moving_shadow_m"]
    illumination_drift: float = _D["illumination_drift"]
    illumination_period_s: float = _D["illumination_period_s"]
    flicker: float = _D["flicker"]
    noise_sigma: float = _D["noise_sigma"]
    defocus_px: float = _D["defocus_px"]
    jpeg_quality: int = _D["jpeg_quality"]
    video_kbps: float = _D["video_kbps"]
    video_codec: str = _D["video_codec"]
    motion_blur_px: float = _D["motion_blur_px"]
    orientation_bins: int = _D["orientation_bins"]
    subpixel: int = _D["subpixel"]

    def __post_init__(self) -> None:
        for k in knobs("appearance"):
            k.check("appearance", getattr(self, k.name))
        require_number("appearance", "n_clusters", self.n_clusters, hi=len(PALETTES[self.palette]))
        if SUPERSAMPLE % self.subpixel:
            raise ValueError(
                f"appearance.subpixel must divide {SUPERSAMPLE} (1, 2 or 4), got {self.subpixel}"
            )
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
    def encoding(self) -> Encoding:
        """The output encoding (JPEG quality, codec, bit rate) as one parameter set."""
        return Encoding(**{name: getattr(self, name) for name in ENCODING})

    @property
    def n_appearances(self) -> int:
        """Number of distinct looks: palette variants plus prominent colours."""
        return self.n_clusters * self.variants_per_cluster + len(PROMINENT_COLOURS)

    @property
    def gait_phases(self) -> int:
        """Gait phases of the sprite bank (1 unless arm swing or body bob is on)."""
        return GAIT_PHASES if (self.arm_swing > 0 or self.gait_bob > 0) else 1

    @property
    def head_turns(self) -> int:
        """Head-turn poses of the sprite bank (1 unless head turns are on)."""
        return HEAD_TURNS if self.head_turn_deg > 0 else 1

    @property
    def n_poses(self) -> int:
        """Poses per orientation: ``gait_phases * head_turns``; pose = ``g * head_turns + h``."""
        return self.gait_phases * self.head_turns


@dataclass(frozen=True)
class SpriteBank:
    """Pre-rendered person geometry (shadow included) and the colours of every appearance.

    Sprite ``k = index(pose, b, py, px)`` is pose ``pose`` facing orientation bin ``b`` with
    sub-pixel phase ``(py, px)``; its head centre lies at
    ``((Z - 1) / 2 + py / P, (Z - 1) / 2 + px / P)`` inside the ``Z x Z`` sprite. The
    premultiplied colour of appearance ``a`` drawn with sprite ``k`` is
    ``cover[k] @ colours[a]`` (see :meth:`premultiplied`).

    Attributes
    ----------
    cover : (K, Z, Z, 3) float32
        Visible coverage of the clothing (arms included), the hair and the face, in [0, 1].
    alpha : (K, Z, Z) float32
        Total coverage in [0, 1]; a shadow is a black, partly transparent part of the sprite.
    solid : (K, Z, Z) bool
        Pixels the person itself (not its shadow) covers at least :data:`SOLID_COVERAGE`.
    head : (K, Z, Z) float32
        Coverage of the head disc (what the ground-truth visibility measures).
    spans : (K, Z, 2) int32
        Per sprite row, the half-open column range ``[lo, hi)`` where alpha is not negligible
        (``lo == hi`` for an empty row); lets the compositing loop skip empty pixels.
    colours : (A, 3, 3) float32
        Per appearance, the BGR colour of the clothing, the hair and the face.
    n_bins, n_poses, subpixel, size : int
        ``B``, the number of poses, ``P`` and ``Z``.
    """

    cover: np.ndarray
    alpha: np.ndarray
    solid: np.ndarray
    head: np.ndarray
    spans: np.ndarray
    colours: np.ndarray
    n_bins: int
    n_poses: int
    subpixel: int
    size: int

    def index(
        self, pose: np.ndarray, bins: np.ndarray, py: np.ndarray, px: np.ndarray
    ) -> np.ndarray:
        """Flat sprite index of ``(pose, orientation bin, phase y, phase x)`` arrays."""
        p = self.subpixel
        return ((pose * self.n_bins + bins) * p + py) * p + px

    def premultiplied(self, appearance: int, k: int) -> np.ndarray:
        """``(Z, Z, 3)`` float32 premultiplied BGR of appearance ``appearance`` on sprite ``k``."""
        return self.cover[k] @ self.colours[appearance]


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
    """``(n_clusters,)`` probabilities of the clothing clusters: ``~ cluster_decay ** k``."""
    w = params.cluster_decay ** np.arange(params.n_clusters, dtype=np.float64)
    return w / w.sum()


def look_colours(params: AppearanceParams, rng: np.random.Generator) -> np.ndarray:
    """``(A, 3, 3)`` float32 BGR of (clothing, hair, face) per appearance, contrast applied.

    Draw order (clothing, hair, skin, then the dark hair only when ``dark_hair_fraction > 0``)
    keeps the looks of specs that leave the new knobs at their defaults.
    """
    n_app = params.n_appearances
    cloth = appearance_colours(params, rng)
    hair = np.array(HAIR_COLOURS, np.float64)[rng.integers(0, len(HAIR_COLOURS), n_app)]
    skin = np.array(SKIN_COLOURS, np.float64)[rng.integers(0, len(SKIN_COLOURS), n_app)]
    if params.dark_hair_fraction > 0:
        dark = rng.random(n_app) < params.dark_hair_fraction
        noise = rng.normal(0.0, params.hair_spread, (n_app, 3))
        hair[dark] = np.array(HAIR_COLOURS[0], np.float64) + noise[dark]
        hair = np.clip(hair, 0, 255)
    ground = np.array(params.ground_bgr, np.float64)
    hair = ground + params.contrast * (hair - ground)
    skin = ground + params.contrast * (skin - ground)
    return np.stack([cloth, hair, skin], axis=1).astype(np.float32)


def _pt(x: float, y: float, one: int) -> tuple[int, int]:
    return int(round(x * one)), int(round(y * one))


def _draw_person(
    size_hi: int,
    centre: float,
    scale: float,
    angle: float,
    params: AppearanceParams,
    gait: float,
    turn: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Draw one person at supersampled resolution in unit colours.

    Returns ``(cover (S, S, 3), mask (S, S), head (S, S))``: the visible coverage of the
    clothing, hair and face (anti-aliased drawing over black in the unit colours, so a real
    colour is the coverages' linear mix), the person's coverage and the head disc's.
    ``gait`` is the gait phase (radians), ``turn`` the head turn (radians).
    """
    shift = 4
    one = 1 << shift
    img = np.zeros((size_hi, size_hi, 3), np.float32)
    mask = np.zeros((size_hi, size_hi), np.float32)
    head = np.zeros((size_hi, size_hi), np.float32)
    cloth, hair, skin = (1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0)
    c = _pt(centre, centre, one)
    deg = math.degrees(angle)
    ca, sa = math.cos(angle), math.sin(angle)
    bs = params.body_scale
    # Gait bob: the body sways sideways under the head (perpendicular to the walking direction).
    bob = params.gait_bob * scale * math.sin(gait)
    bx, by = centre - bob * sa, centre + bob * ca
    if params.arm_swing > 0:
        # Arms at the shoulder ends, swinging in opposition along the walking direction.
        swing = params.arm_swing * scale * math.sin(gait)
        axes_arm = _pt(ARM_AXES[0] * scale, ARM_AXES[1] * scale * bs, one)
        for side in (-1.0, 1.0):
            off = side * ARM_OFFSET * scale * bs
            fwd = side * swing
            ac = _pt(bx - off * sa + fwd * ca, by + off * ca + fwd * sa, one)
            cv2.ellipse(img, ac, axes_arm, deg, 0, 360, cloth, -1, cv2.LINE_AA, shift)
            cv2.ellipse(mask, ac, axes_arm, deg, 0, 360, 1.0, -1, cv2.LINE_AA, shift)
    # Shoulders: long axis across the walking direction, slightly behind the head.
    back = 0.05 * scale
    sc = _pt(bx - back * ca, by - back * sa, one)
    axes = _pt(SHOULDER_DEPTH * scale * bs, SHOULDER_HALF_WIDTH * scale * bs, one)
    cv2.ellipse(img, sc, axes, deg, 0, 360, cloth, -1, cv2.LINE_AA, shift)
    cv2.ellipse(mask, sc, axes, deg, 0, 360, 1.0, -1, cv2.LINE_AA, shift)
    r = int(round(HEAD_RADIUS * scale * one))
    cv2.circle(img, c, r, hair, -1, cv2.LINE_AA, shift)
    cv2.circle(mask, c, r, 1.0, -1, cv2.LINE_AA, shift)
    cv2.circle(head, c, r, 1.0, -1, cv2.LINE_AA, shift)
    # Face: a skin crescent on the looking side of the head. From above mostly hair is seen;
    # the face is a thin crescent at the front of the head, so the head centre (the
    # ground-truth point) stays hair-coloured.
    look = angle + turn
    fwd = FACE_OFFSET * scale
    fc = _pt(centre + fwd * math.cos(look), centre + fwd * math.sin(look), one)
    face_axes = _pt(0.07 * scale, 0.13 * scale, one)
    cv2.ellipse(img, fc, face_axes, math.degrees(look), 0, 360, skin, -1, cv2.LINE_AA, shift)
    return img, mask, head


def _shadow_hi(
    size_hi: int, centre: float, scale: float, angle: float, blur_hi: float, body_scale: float = 1.0
) -> np.ndarray:
    """Soft shadow coverage at supersampled resolution, offset towards the lower right."""
    hi = np.zeros((size_hi, size_hi), np.float32)
    one = 16
    cx = centre + SHADOW_OFFSET[0] * scale
    cy = centre + SHADOW_OFFSET[1] * scale
    cv2.ellipse(
        hi,
        (int(round(cx * one)), int(round(cy * one))),
        (int(round(0.33 * scale * body_scale * one)), int(round(0.5 * scale * body_scale * one))),
        math.degrees(angle),
        0,
        360,
        1.0,
        -1,
        cv2.LINE_AA,
        4,
    )
    return cv2.GaussianBlur(hi, (0, 0), blur_hi)


def sprite_size(params: AppearanceParams) -> int:
    """Sprite side ``Z`` in pixels: the template plus room for the body, arms and shadow."""
    s = params.template_px
    grow = max(params.body_scale, 1.0)
    # Reach beyond the body's half width (s * grow / 2), in templates: the shadow's offset
    # and blur (its size grows with the body), the bobbing shoulders, the swinging arms.
    reach = 0.0
    if params.shadow > 0:
        reach = SHADOW_REACH
    if params.gait_bob > 0:
        reach = max(reach, params.gait_bob + 0.05)
    if params.arm_swing > 0:
        reach = max(reach, params.arm_swing + ARM_AXES[0] + params.gait_bob - 0.3)
    pad = int(math.ceil(reach * s)) + 1 if reach > 0 else 0
    return int(math.ceil(s * grow)) + 2 + 2 * pad


def build_sprite_bank(params: AppearanceParams, rng: np.random.Generator) -> SpriteBank:
    """Render every ``(pose, orientation, sub-pixel phase)`` sprite, shadow included.

    Orientation bin ``b`` faces the image direction ``angle = 2 pi b / B`` (``u`` right,
    ``v`` down). Pose ``g * H + h`` is gait phase ``2 pi g / G`` and head turn
    ``(h - (H - 1) / 2) * head_turn_deg`` with ``G = params.gait_phases`` and
    ``H = params.head_turns``.
    """
    s = params.template_px
    z = sprite_size(params)
    p = params.subpixel
    ss = SUPERSAMPLE
    if ss % p:
        raise ValueError(f"appearance.subpixel must divide {ss}, got {p}")
    step = ss // p
    nb = params.orientation_bins
    n_g, n_h = params.gait_phases, params.head_turns
    n_pose = n_g * n_h
    colours = look_colours(params, rng)
    size_hi = z * ss
    pad_hi = ss  # one low-res pixel of room for the sub-pixel shifts
    # Hi-res coordinate of the low-res pixel centre (Z - 1) / 2, inside the padded canvas.
    centre_hi = ((z - 1) / 2.0 + 0.5) * ss - 0.5 + pad_hi
    cover = np.zeros((n_pose, nb, p, p, z, z, 3), np.float32)
    alpha = np.zeros((n_pose, nb, p, p, z, z), np.float32)
    solid = np.zeros((n_pose, nb, p, p, z, z), np.float32)
    head = np.zeros((n_pose, nb, p, p, z, z), np.float32)
    for b in range(nb):
        angle = 2.0 * math.pi * b / nb
        shadow = None
        if params.shadow > 0:
            shadow = params.shadow * _shadow_hi(
                size_hi + 2 * pad_hi,
                centre_hi,
                s * ss,
                angle,
                max(0.6, SHADOW_BLUR * s) * ss,
                params.body_scale,
            )
        for g in range(n_g):
            for h in range(n_h):
                pose = g * n_h + h
                turn = math.radians((h - (n_h - 1) / 2.0) * params.head_turn_deg)
                img, mask, hd = _draw_person(
                    size_hi + 2 * pad_hi,
                    centre_hi,
                    s * ss,
                    angle,
                    params,
                    2.0 * math.pi * g / n_g,
                    turn,
                )
                full = mask if shadow is None else mask + shadow * (1.0 - mask)
                for py in range(p):
                    for px in range(p):
                        # Shift the drawing by (py, px) / P low-res pixels = step * (py, px).
                        y0 = pad_hi - py * step
                        x0 = pad_hi - px * step
                        win = (slice(y0, y0 + size_hi), slice(x0, x0 + size_hi))
                        for src, dst in ((img, cover), (full, alpha), (mask, solid), (hd, head)):
                            dst[pose, b, py, px] = cv2.resize(
                                src[win], (z, z), interpolation=cv2.INTER_AREA
                            )
    alpha = alpha.reshape(-1, z, z)
    visible = alpha > ALPHA_EPS
    any_row = visible.any(axis=2)
    lo = np.where(any_row, np.argmax(visible, axis=2), 0)
    hi = np.where(any_row, z - np.argmax(visible[:, :, ::-1], axis=2), 0)
    alpha[~visible] = 0.0
    cover = cover.reshape(-1, z, z, 3)
    cover[~visible] = 0.0
    head = head.reshape(-1, z, z)
    head[~visible] = 0.0
    return SpriteBank(
        cover=cover,
        alpha=alpha,
        solid=(solid.reshape(-1, z, z) >= SOLID_COVERAGE) & visible,
        head=head,
        spans=np.stack([lo, hi], -1).astype(np.int32),
        colours=colours,
        n_bins=nb,
        n_poses=n_pose,
        subpixel=p,
        size=z,
    )


AppearanceParams.__doc__ = (
    (AppearanceParams.__doc__ or "").rstrip()
    + "\n"
    + "\n".join(
        "    " + line if line else line for line in attributes_doc("appearance").splitlines()
    )
)
