"""Every rendering knob of a sequence spec, in one table: :data:`KNOBS`.

A knob is one field of a spec's ``[appearance]`` section
(:class:`crowdsim.appearance_model.AppearanceParams`) or one of the camera's motion fields
(shake, and the drone profile's drift, rotation and zoom). Its
row holds everything the rest of the project needs to know about it, so adding a knob means
adding a row here, its field to ``AppearanceParams`` and drawing it in the renderer:

* **range** -- ``lo`` / ``hi`` (closed unless ``lo_open``), or ``choices``; the renderer's
  validation (:meth:`Knob.check`) reads it, so an out-of-range value is refused naming the field;
* **default** -- the value of a spec that does not set the knob (:func:`defaults`);
* **hard end and calibration axis** -- the value the difficulty scale moves the knob to at 1,
  and whether it moves with the ``scene`` or the ``camera`` scalar (:func:`knob_values`, read
  by ``crowdsim calibrate`` and the tuning episodes' difficulty);
* **difficulty group** -- the name ``crowdsim difficulty`` resets it under
  (:func:`difficulty_groups`);
* **doc** -- its meaning and unit, shown by the spec docs (:func:`reference`, appended to
  :mod:`synth_data.spec` and ``crowdsim generate --help``) and by ``AppearanceParams``.

The difficulty scale moves a knob linearly from the spec's own value (0) to ``hard`` (1). The
video bit rate moves on a log scale instead, from ``easy`` just after the codec switches on at
``on`` to ``hard`` at 1: a codec's quality is roughly linear in the log of its bit rate; a
spec whose own codec is on moves from its own bit rate to ``hard`` on that scale.

>>> knob("noise_sigma").hard, knob("noise_sigma").axis, knob("noise_sigma").group
(24.0, 'camera', 'noise+codec')
>>> list(difficulty_groups())[:3]
['look-alike', 'packing', 'gait']
>>> knob("video_kbps").at(0.05, 0.0), knob("video_kbps").at(1.0, 0.0)
(0.0, 150.0)
"""

from __future__ import annotations

import math
import textwrap
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from crowdsim.checks import require_choice, require_number

SECTIONS: tuple[str, ...] = ("appearance", "camera")
"""Spec sections a knob may live in."""
AXES: tuple[str, ...] = ("scene", "camera")
"""Calibration axes, in the order the difficulty scale lists them."""
PROFILES: tuple[str, ...] = ("hard", "static")
"""Ends of the difficulty scale: ``"hard"`` moves every knob to its hard end (shake, strong
noise and low bit rates included); ``"static"`` keeps the image formation within what real
footage from a fixed camera has (each knob's ``static`` end and its ``source``): no shake,
no camera motion blur, and the scene knobs at their hard ends."""


@dataclass(frozen=True)
class Knob:
    """One row of :data:`KNOBS`.

    Attributes
    ----------
    name : str
        Field name in the spec section (and of ``AppearanceParams`` / ``Camera``).
    section : str
        ``"appearance"`` or ``"camera"``.
    default : Any
        Value when the spec leaves the knob out.
    doc : str
        Meaning and unit, one sentence or two.
    kind : str
        ``"float"``, ``"int"``, ``"bool"``, ``"choice"`` or ``"bgr"`` (three grey levels).
    lo, hi : float
        Allowed range (``hi = inf`` for none); ``lo_open`` excludes ``lo``.
    choices : tuple of str
        Allowed values of a ``"choice"`` knob.
    off_below : float
        A value in ``(0, off_below)`` is refused: 0 switches the knob off, and anything smaller
        than ``off_below`` would not mean what it says (a bit rate that rounds to nothing).
    hard : float, optional
        The difficulty scale's value at 1; ``None`` for a knob the scale never moves.
    axis : str, optional
        ``"scene"`` or ``"camera"``: the calibration scalar that moves the knob.
    group : str, optional
        Difficulty group (``crowdsim difficulty``); set exactly when ``axis`` is.
    easy, on : float, optional
        Log-scale knobs only: the value just after the knob switches on at axis value ``on``
        (below ``on`` it stays at ``default``, i.e. off).
    digits : int
        Decimals a calibrated value is rounded to (``int`` knobs: whole numbers).
    static : float, optional
        The scale's end under the ``"static"`` profile (:data:`PROFILES`): the harshest value
        real footage from a fixed surveillance or web camera has. ``None``: the same as
        ``hard`` (a property of the scene, not of the camera).
    source : str
        Where the realistic range of a ``static`` end comes from.
    """

    name: str
    section: str
    default: Any
    doc: str
    kind: str = "float"
    lo: float = -math.inf
    hi: float = math.inf
    lo_open: bool = False
    choices: tuple[str, ...] = ()
    off_below: float = 0.0
    hard: float | None = None
    axis: str | None = None
    group: str | None = None
    easy: float | None = None
    on: float | None = None
    digits: int = 4
    static: float | None = None
    source: str = ""

    def __post_init__(self) -> None:
        if self.section not in SECTIONS:
            raise ValueError(f"knob {self.name}: section must be one of {SECTIONS}")
        if (self.axis is None) != (self.group is None) or (self.axis is None) != (
            self.hard is None
        ):
            raise ValueError(f"knob {self.name}: hard, axis and group go together")
        if self.axis is not None and self.axis not in AXES:
            raise ValueError(f"knob {self.name}: axis must be one of {AXES}")
        if (self.easy is None) != (self.on is None):
            raise ValueError(f"knob {self.name}: easy and on go together")
        if self.static is not None and self.hard is None:
            raise ValueError(f"knob {self.name}: a static end needs a hard end")

    def end(self, profile: str = "hard") -> float:
        """The scale's value at 1 under ``profile`` (:data:`PROFILES`)."""
        require_choice("", "profile", profile, PROFILES)
        if self.hard is None:
            raise ValueError(f"knob {self.name} is not on the difficulty scale")
        return self.hard if profile == "hard" or self.static is None else self.static

    @property
    def integer(self) -> bool:
        return self.kind == "int"

    @property
    def range_text(self) -> str:
        """The allowed values in words, as the error messages and the docs give them."""
        if self.kind == "choice":
            return " | ".join(self.choices)
        if self.kind == "bool":
            return "true | false"
        lo = "(" if self.lo_open else "["
        hi = f"{self.hi:g}]" if math.isfinite(self.hi) else "inf)"
        text = f"{lo}{self.lo:g}, {hi}"
        if self.kind == "bgr":
            return f"three of {text}"
        return f"0 or [{self.off_below:g}, {self.hi:g}]" if self.off_below > 0 else text

    def check(self, owner: str, value: Any) -> None:
        """Raise ``ValueError`` naming ``owner.name`` and ``value`` when out of range."""
        if self.kind == "choice":
            require_choice(owner, self.name, value, self.choices)
        elif self.kind == "bool":
            if not isinstance(value, (bool, np.bool_)):
                raise ValueError(f"{owner}.{self.name} must be true or false, got {value!r}")
        elif self.kind == "bgr":
            if isinstance(value, (str, bytes)) or len(value) != 3:
                raise ValueError(
                    f"{owner}.{self.name} must be three numbers in [0, 255], got {value!r}"
                )
            for v in value:
                require_number(owner, self.name, v, lo=self.lo, hi=self.hi)
        else:
            require_number(
                owner,
                self.name,
                value,
                lo=self.lo,
                hi=self.hi if math.isfinite(self.hi) else None,
                lo_open=self.lo_open,
                integer=self.integer,
            )
            if 0 < value < self.off_below:
                raise ValueError(
                    f"{owner}.{self.name} must be 0 (off) or at least {self.off_below:g}, "
                    f"got {value!r}"
                )

    def at(self, s: float, base: float, profile: str = "hard") -> float:
        """The knob's value at position ``s`` in [0, 1] of the difficulty scale from ``base``,
        towards its end under ``profile`` (:meth:`end`)."""
        end = self.end(profile)
        if self.on is not None and base > 0:
            # on in the spec itself: from its own rate (0) to the end on the log scale; the
            # switch-on below would turn its codec off and jump to ``easy`` (easier, not harder)
            return round(base * (end / base) ** s, self.digits)
        if self.on is not None:
            if s < self.on:
                return float(self.default)
            f = (s - self.on) / (1.0 - self.on)
            return round(self.easy * (end / self.easy) ** f, self.digits)
        v = base + s * (end - base)
        return int(round(v)) if self.integer else round(v, self.digits)


def _a(name: str, default: Any, doc: str, **kw: Any) -> Knob:
    return Knob(name=name, section="appearance", default=default, doc=doc, **kw)


KNOBS: tuple[Knob, ...] = (
    # -- look-alike heads and clothing (scene axis)
    _a("dark_hair_fraction", 0.0, "Share of looks with the common dark hair colour plus noise of "
       "hair_spread grey levels; 0 draws hair from four colours, 1 makes every head a "
       "near-identical dark disc from above.", lo=0, hi=1, hard=1.0, axis="scene",
       group="look-alike"),
    _a("cluster_spread", 10.0, "Standard deviation (grey levels) of the clothing variants around "
       "their cluster centre; small = tight clusters of look-alike people.", lo=0, hi=100,
       hard=3.0, axis="scene", group="look-alike"),
    _a("cluster_decay", 0.5, "Weight ratio of successive clothing clusters (cluster k is worn with "
       "probability ~ cluster_decay^k); smaller = one denser dominant cluster.", lo=0, hi=1,
       lo_open=True, hard=0.3, axis="scene", group="look-alike"),
    _a("contrast", 1.0, "Scale of the clothing, hair and skin colours' difference from the ground "
       "colour; below 1 people blend into the ground.", lo=0.05, hi=2, hard=0.2, axis="scene",
       group="look-alike"),
    # -- packing
    _a("body_scale", 1.0, "Size of the shoulders, arms and shadow relative to the template (the "
       "head and the ground-truth box keep theirs); above 1 bodies touch at marathon density.",
       lo=0.5, hi=2, hard=1.6, axis="scene", group="packing"),
    # -- appearance change over time
    _a("arm_swing", 0.0, "Forward/backward swing of the arms over a stride, fraction of the "
       "template (0 = no arms drawn).", lo=0, hi=0.5, hard=0.4, axis="scene", group="gait"),
    _a("gait_bob", 0.0, "Side-to-side bob of the body under the head over a stride, fraction of "
       "the template.", lo=0, hi=0.5, hard=0.25, axis="scene", group="gait"),
    _a("head_turn_deg", 0.0, "Amplitude of slow head turns (the face crescent turns away from the "
       "walking direction), degrees.", lo=0, hi=90, hard=60.0, axis="scene", group="gait"),
    # -- clutter
    _a("distractor_density", 0.0, "Static head-like distractors (bollards, litter, road-marking "
       "dashes) baked into the ground, per square metre.", lo=0, hi=10, hard=0.6, axis="scene",
       group="clutter"),
    _a("moving_shadow_density", 0.0, "Soft, head-sized moving shadows (of people and objects "
       "outside the view) per square metre; they drift at walking speed.", lo=0, hi=10,
       hard=0.15, axis="scene", group="clutter"),
    # -- image formation (camera axis)
    _a("noise_sigma", 3.0, "Sensor noise standard deviation, grey levels.", lo=0, hi=50,
       hard=24.0, axis="camera", group="noise+codec", static=10.0,
       source="Liu et al., 'Automatic estimation and removal of noise from a single image', "
       "PAMI 2008: real CCD noise up to sigma ~10 grey levels at high gain; daylight "
       "surveillance 2-6"),
    _a("defocus_px", 0.0, "Gaussian defocus blur sigma, pixels (0 = sharp).", lo=0, hi=20,
       hard=2.0, axis="camera", group="blur", static=1.5,
       source="web and CCTV video resized from a larger sensor or slightly out of focus: "
       "a Gaussian PSF of sigma 0.5-1.5 px at the delivered resolution"),
    _a("flicker", 0.0, "Standard deviation of an independent per-frame relative gain "
       "(illumination flicker, e.g. 50 Hz lights against the shutter).", lo=0, hi=0.5,
       hard=0.08, axis="camera", group="flicker", static=0.04,
       source="fluorescent and LED lighting on 50/60 Hz mains against a short shutter: "
       "frame-to-frame gain changes of a few per cent"),
    _a("motion_blur_px", 0.0, "Length of a horizontal-ish camera motion-blur kernel, pixels "
       "(0 = off).", lo=0, hi=30, hard=3.5, axis="camera", group="blur", static=0.0,
       source="a fixed camera does not move during the exposure"),
    _a("jpeg_quality", 90, "JPEG quality of the written frames (output encoding).", kind="int",
       lo=1, hi=100, hard=40, axis="camera", group="noise+codec", static=60,
       source="frames dumped from web video and stored as JPEG: quality 60-95 (IJG scale)"),
    Knob("jitter_px", "camera", 0.0, "Camera shake: standard deviation (pixels) of a smooth, "
         "seeded per-frame image translation (hand-held or wind-shaken camera).", lo=0, hi=200,
         hard=3.0, axis="camera", group="shake", static=0.0,
         source="the papers' footage comes from fixed cameras (the ucf9-shake suite keeps shake)"),
    _a("video_kbps", 0.0, "Video-codec bit rate, kbit/s: frames pass through video_codec at this "
       "rate before the JPEGs are made (output encoding; 0 = no codec; real 720p CCTV runs at "
       "roughly 1000-4000 kbit/s).", lo=0, hi=1_000_000, off_below=1.0, hard=150.0,
       axis="camera", group="noise+codec", easy=4000.0, on=0.1, digits=1, static=400.0,
       source="low-rate web video (H.264 at 240p-360p streams at 0.3-0.7 Mbit/s) and CCTV "
       "sub-streams (256-512 kbit/s)"),
    # -- settings the difficulty scale never moves
    _a("template_px", 12, "Template (sprite) size in pixels: shoulder width and the "
       "ground-truth box side.", kind="int", lo=4, hi=64),
    _a("palette", "dull", "Clothing palette (crowdsim.appearance_model.PALETTES).",
       kind="choice", choices=("dark", "dull", "sport", "white")),
    _a("n_clusters", 3, "How many palette clusters are worn (the first ones; at most the "
       "palette's size).", kind="int", lo=1, hi=16),
    _a("variants_per_cluster", 4, "Colour variants drawn around each cluster centre.",
       kind="int", lo=1, hi=16),
    _a("prominent_fraction", 0.05, "Share of people in distinct colours (paper 2's queens) when "
       "the trajectories carry no prominent attribute.", lo=0, hi=1),
    _a("hair_spread", 4.0, "Standard deviation (grey levels) of the dark hair colour.", lo=0,
       hi=100),
    _a("heads_on_top", False, "Draw every head after all bodies, so only heads hide heads "
       "(default: each person whole, in depth order).", kind="bool"),
    _a("ground_bgr", (115, 125, 130), "Mean ground colour, BGR.", kind="bgr", lo=0, hi=255),
    _a("ground_texture", 10.0, "Standard deviation (grey levels) of the ground texture.", lo=0,
       hi=80),
    _a("paving_m", 0.0, "Paving slab size, metres (0 = no slabs).", lo=0, hi=100),
    _a("shadow", 0.35, "Darkening of the ground under a person's shadow, in [0, 1].", lo=0, hi=1),
    _a("sway_deg", 8.0, "Amplitude of the shoulder sway around the walking direction, degrees.",
       lo=0, hi=45),
    _a("head_turn_period_s", 4.0, "Mean period of the head turns, seconds (each person's is "
       "0.5-1.5 times this).", lo=0, lo_open=True),
    _a("moving_shadow_m", 0.6, "Diameter of a moving shadow, metres.", lo=0, lo_open=True),
    _a("illumination_drift", 0.06, "Relative amplitude of the slow global illumination change.",
       lo=0, hi=0.5),
    _a("illumination_period_s", 30.0, "Period of the illumination change, seconds.", lo=0,
       lo_open=True),
    _a("video_codec", "h264", "Codec of video_kbps: h264 (libx264 through PyAV) or mpeg4 (MPEG-4 "
       "part 2) (output encoding).", kind="choice", choices=("h264", "mpeg4")),
    _a("orientation_bins", 32, "Orientation bins of the sprite bank.", kind="int", lo=4, hi=128),
    _a("subpixel", 2, "Sub-pixel phases per axis of the sprite bank (1, 2 or 4: it must divide "
       "the 8x supersampling).", kind="int", lo=1, hi=4),
    Knob("jitter_frames", "camera", 12.0, "Correlation time of the camera shake, frames (small = "
         "fast shake, 1 = nearly independent from frame to frame).", lo=0, lo_open=True),
    # -- the drone profile: slow drift, rotation and zoom of the whole view (0 = off)
    Knob("drift_px", "camera", 0.0, "Drone profile: amplitude (pixels) of a slow, seeded drift "
         "of the view, each axis (a hovering drone or a slowly panning camera; 0 = off).", lo=0,
         hi=400),
    Knob("rotate_deg", "camera", 0.0, "Drone profile: amplitude (degrees) of a slow, seeded "
         "rotation of the view about the frame centre (a drone's yaw; 0 = off).", lo=0, hi=20),
    Knob("zoom", "camera", 0.0, "Drone profile: relative amplitude of a slow, seeded zoom (a "
         "drone's altitude; 0.05 = +-5 %; 0 = off).", lo=0, hi=0.3),
    Knob("drone_frames", "camera", 150.0, "Drone profile: time scale of the drift, rotation and "
         "zoom, frames (each is a sum of three sinusoids with periods 0.5-1.5 times this).",
         lo=1),
)  # fmt: skip
"""The table. Rows on the difficulty scale come first, in the order it lists them."""

_BY_NAME: dict[str, Knob] = {k.name: k for k in KNOBS}
ENCODING: tuple[str, ...] = ("jpeg_quality", "video_kbps", "video_codec")
"""The output-encoding knobs (:class:`crowdsim.appearance_model.Encoding`)."""


def knob(name: str) -> Knob:
    """The row of ``name``; ``KeyError`` lists the knobs."""
    try:
        return _BY_NAME[name]
    except KeyError:
        raise KeyError(f"no knob {name!r}; the knobs are {sorted(_BY_NAME)}") from None


def knobs(section: str | None = None, *, axis: str | None = None) -> Iterator[Knob]:
    """The rows of ``section`` (all by default), of calibration ``axis`` only if given."""
    for k in KNOBS:
        if (section is None or k.section == section) and (axis is None or k.axis == axis):
            yield k


def defaults(section: str) -> dict[str, Any]:
    """``{name: default}`` of every knob of ``section``."""
    return {k.name: k.default for k in knobs(section)}


def scaled() -> tuple[Knob, ...]:
    """The knobs on the difficulty scale: every ``scene`` one, then every ``camera`` one."""
    return tuple(k for a in AXES for k in knobs(axis=a))


def difficulty_groups() -> dict[str, tuple[str, ...]]:
    """``{group: knob names}`` in the order the table first names each group."""
    out: dict[str, tuple[str, ...]] = {}
    for k in scaled():
        out[k.group] = (*out.get(k.group, ()), k.name)  # type: ignore[index]
    return out


# ------------------------------------------------------------------ the difficulty scale
def spec_value(spec: Any, k: Knob) -> Any:
    """The value knob ``k`` has in ``spec`` (a :class:`synth_data.spec.SequenceSpec`)."""
    if k.section == "appearance":
        return getattr(spec.appearance, k.name)
    return spec.camera.get(k.name, k.default)


def knob_values(
    spec: Any, scene: float, camera: float, profile: str = "hard"
) -> dict[tuple[str, str], Any]:
    """Spec fields ``{(section, name): value}`` at the two difficulty scalars in [0, 1].

    Every knob on the scale moves from the spec's own value (0) to its end under ``profile``
    (1; :data:`PROFILES`) with the scalar of its axis (:meth:`Knob.at`).
    """
    at = {"scene": scene, "camera": camera}
    for axis, v in at.items():
        if isinstance(v, bool) or not (isinstance(v, (int, float)) and 0.0 <= v <= 1.0):
            raise ValueError(f"calibration {axis} must be in [0, 1], got {v!r}")
    return {
        (k.section, k.name): k.at(at[k.axis], float(spec_value(spec, k)), profile)  # type: ignore[index]
        for k in scaled()
    }


def apply_knobs(spec: Any, values: Mapping[tuple[str, str], Any]) -> Any:
    """``spec`` with the knob values ``{(section, name): value}`` set (and validated)."""
    app = replace(spec.appearance, **{n: v for (s, n), v in values.items() if s == "appearance"})
    cam = dict(spec.camera)
    for (s, n), v in values.items():
        if s == "camera":
            knob(n).check("camera", v)
            cam[n] = v
    return replace(spec, appearance=app, camera=cam)


# ------------------------------------------------------------------ docs
def _toml(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return f'"{value}"'
    if isinstance(value, tuple):
        return "[" + ", ".join(_toml(v) for v in value) + "]"
    return repr(value)


def _static_text(k: Knob) -> str:
    """The harshest value real footage from a fixed camera has, in words: ``up to`` a
    ceiling, ``down to`` a floor (JPEG quality, bit rate: lower is harsher), ``none`` for 0."""
    easy = k.easy if k.easy is not None else k.default
    lower_is_harsher = k.hard is not None and k.hard < easy
    if k.static == 0 and not lower_is_harsher:
        return "none (0)"
    return f"{'down to' if lower_is_harsher else 'up to'} {k.static:g}"


def reference(section: str | None = None) -> str:
    """The knobs as plain text (the spec docs): per knob ``section.name = default``, its range,
    its place on the difficulty scale, then its meaning, wrapped at 88 columns."""
    out = []
    for k in knobs(section):
        head = f"{k.section}.{k.name} = {_toml(k.default)}    range {k.range_text}"
        if k.axis is not None:
            head += f"    difficulty: {k.axis} axis -> {k.hard:g} ({k.group})"
        out.append(head)
        doc = k.doc
        if k.static is not None:
            doc += f" Realistic for a fixed camera: {_static_text(k)} ({k.source})."
        out.extend(textwrap.wrap(doc, 88, initial_indent="    ", subsequent_indent="    "))
    return "\n".join(out)


def attributes_doc(section: str) -> str:
    """numpydoc ``Attributes`` entries of the knobs of ``section`` (for class docstrings)."""
    types = {
        "float": "float",
        "int": "int",
        "bool": "bool",
        "choice": "str",
        "bgr": "(int, int, int)",
    }
    out = []
    for k in knobs(section):
        extra = "" if k.axis is None else f" Difficulty scale: {k.axis} axis, hard end {k.hard:g}."
        text = f"{k.doc} Range {k.range_text}, default {k.default!r}.{extra}"
        out.append(f"{k.name} : {types[k.kind]}")
        out.extend(textwrap.wrap(text, 88, initial_indent="    ", subsequent_indent="    "))
    return "\n".join(out)
