"""Sequence spec files (TOML or YAML): scenario, camera, appearance, seed (SPEC §4).

A spec describes one sequence. Example (TOML)::

    name = "seq3"            # folder name: letters, digits, '.', '-', '_' (not manifest.json)
    seed = 3                 # seeds simulation and rendering
    frames = 144             # frames written (one simulation step per frame)
    fps = 25.0               # frame rate in [5, 1000]; simulation dt = 1 / fps
    warmup_steps = 50        # simulated steps dropped before frame 1
    description = "marathon, dense"

    [scenario]               # crowdsim.scenarios.make_scenario(name, **rest)
    name = "marathon"
    n_agents = 175
    density = 2.0

    [camera]                 # crowdsim.camera.Camera; omitted size/scale fit the crowd
    tilt_deg = 0.0
    jitter_px = 0.0          # camera shake, pixels (standard deviation)
    # jitter_frames = 12.0   shake correlation time in frames (small = fast shake)
    # drift_px = 0.0         drone profile: slow drift / rotate_deg / zoom (see below)
    # px_per_m = 28.0        default: appearance.template_px / 0.5 m
    # width = 1280           default: the trajectories' extent, at most max_width
    # height = 720
    # center = [0.0, 0.0]    default: centre of the extent
    # ground_margin_px = 0   least ground drawn beyond the frame (default: the shake's)
    max_width = 1920
    max_height = 1080

    [appearance]             # crowdsim.appearance_model.AppearanceParams: the knobs below
    template_px = 14
    noise_sigma = 3.0
    dark_hair_fraction = 0.6 # every knob defaults to off / the earlier look

    [output]
    images = true            # img1/*.jpg
    video = false            # video.mp4

    [[events]]               # optional: what changes part-way (crowdsim.events)
    kind = "lighting"        # lighting | noise | shake | stop | surge
    start = 60               # first frame it acts on (0-based, after the warm-up)
    frames = 40              # how long; 0 = until the end
    magnitude = 0.5          # factor / sigma / px / fraction / factor, by kind

    [calibration]            # free-form record (numbers and strings), not used to render
    paper_b_ncc_15px = 85.54 # the target of crowdsim calibrate --anchor b-ncc
    paper_ncc_15px = 58.0    # ... and of --anchor ncc11

Validation happens on load; every error names the file, the field and the value, e.g.
``seq3.toml: camera.tilt_deg must be in [0, 60), got 75``.

The rendering knobs (``[appearance]`` and the camera motion: shake and drone profile), from
:data:`crowdsim.knobs.KNOBS` (also printed by ``crowdsim generate --help``)::

"""

from __future__ import annotations

import functools
import hashlib
import json
import math
import os
import re
import sys
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from crowdsim.appearance_model import AppearanceParams
from crowdsim.events import Event, parse_events
from crowdsim.knobs import knobs, reference

__doc__ = (__doc__ or "") + "\n".join("    " + line for line in reference().splitlines()) + "\n"

NAME_RE = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]*$")
RESERVED_NAMES: tuple[str, ...] = ("manifest.json", "tune_jobs.json")
"""Sequence names taken by files beside the sequences (the jobs runner's manifests)."""

TOP_FIELDS: dict[str, tuple[type | tuple[type, ...], bool]] = {
    "name": (str, True),
    "seed": (int, True),
    "frames": (int, True),
    "fps": ((int, float), False),
    "warmup_steps": (int, False),
    "description": (str, False),
}
"""Top-level key -> (type, required)."""
SECTIONS: tuple[str, ...] = ("scenario", "camera", "appearance", "output", "calibration")
LISTS: tuple[str, ...] = ("events",)
"""Top-level lists of tables (``[[events]]`` in TOML)."""
CAMERA_FIELDS: dict[str, type | tuple[type, ...]] = {
    "px_per_m": (int, float),
    "width": int,
    "height": int,
    "center": list,
    "tilt_deg": (int, float),
    "distance_m": (int, float),
    **{k.name: (int, float) for k in knobs("camera")},  # shake and drone profile
    "max_width": int,
    "max_height": int,
    "margin_m": (int, float),
    "ground_margin_px": int,
}
MAX_SIDE_PX: int = 8192
"""Largest frame width or height, px (as ``crowdsim render``)."""
PX_PER_M: tuple[float, float] = (1e-3, 1e4)
"""Allowed camera scale, px/m."""
OUTPUT_FIELDS: dict[str, type] = {"images": bool, "video": bool}
MAX_FRAMES: int = 1_000_000
MIN_FPS: float = 5.0
"""Lowest frame rate: the simulation steps ``1 / fps`` seconds, and
:class:`crowdsim.params.SocialForceParams` integrates stably up to ``dt = 0.2`` s."""
MAX_WARMUP_STEPS: int = 100_000


@dataclass(frozen=True)
class SequenceSpec:
    """A validated sequence spec.

    Attributes
    ----------
    name : str
        Sequence (folder) name.
    seed : int
        Seed of the simulation and of the rendering.
    frames : int
        Frames to write.
    fps : float
        Frames per second; the simulation steps ``1 / fps`` seconds per frame.
    warmup_steps : int
        Simulation steps run and dropped before the first frame.
    scenario : dict
        ``{"name": ..., **parameters}`` for :func:`crowdsim.scenarios.make_scenario`.
    camera : dict
        Camera fields (see :data:`CAMERA_FIELDS`).
    appearance : AppearanceParams
    output : dict
        ``{"images": bool, "video": bool}``.
    events : tuple of crowdsim.events.Event
        What changes part-way through the sequence (lighting, noise, shake, stop, surge);
        listed in :meth:`to_dict` and the digest only when there are any.
    calibration : dict
        Free-form calibration record (not part of :meth:`digest`).
    description : str
    source : str
        File the spec came from ("" for built-in tables).
    """

    name: str
    seed: int
    frames: int
    fps: float = 25.0
    warmup_steps: int = 0
    scenario: dict[str, Any] = field(default_factory=dict)
    camera: dict[str, Any] = field(default_factory=dict)
    appearance: AppearanceParams = field(default_factory=AppearanceParams)
    output: dict[str, bool] = field(default_factory=lambda: {"images": True, "video": False})
    events: tuple[Event, ...] = ()
    calibration: dict[str, Any] = field(default_factory=dict)
    description: str = ""
    source: str = ""

    def to_dict(self) -> dict[str, Any]:
        """JSON-serialisable form (what ``meta.json`` stores under ``spec``)."""
        return {
            "name": self.name,
            "seed": self.seed,
            "frames": self.frames,
            "fps": self.fps,
            "warmup_steps": self.warmup_steps,
            "description": self.description,
            "scenario": dict(self.scenario),
            "camera": dict(self.camera),
            "appearance": self.appearance.to_dict(),
            "output": dict(self.output),
            "calibration": dict(self.calibration),
        } | ({"events": [e.to_dict() for e in self.events]} if self.events else {})

    def digest(self) -> str:
        """SHA-256 of everything that changes the output (not description/calibration)."""
        d = self.to_dict()
        d.pop("description")
        d.pop("calibration")
        if d["scenario"].get("name") == "station":
            # the station's route layout 1 is what every station spec simulated before the
            # field existed: without the key, a spec pinned to it keeps its digest (the same
            # sequence), and one that takes the new default is a new one
            routes = d["scenario"].pop("routes", 2)
            if routes != 1:
                d["scenario"]["routes"] = routes
        return hashlib.sha256(json.dumps(d, sort_keys=True).encode()).hexdigest()

    def truncated(self, frames: int | None) -> SequenceSpec:
        """This spec with at most ``frames`` frames (unchanged for None), less the events
        that start after the cut (they act on no frame, and a spec holding them would not
        load again). The crowd of the kept frames is the whole sequence's (the same simulation,
        step for step), but the camera is framed on that crowd alone
        (:func:`synth_data.scene.camera_for` fits its size and centre to the crowd's extent
        over the frames it is given), so the pixels and the boxes are those of the whole
        sequence's first ``frames`` frames only where the spec fixes ``camera.width``,
        ``camera.height`` and ``camera.center``."""
        if frames is None:
            return self
        if frames < 1:
            raise ValueError(f"--frames must be >= 1, got {frames}")
        n = min(self.frames, int(frames))
        return replace(self, frames=n, events=tuple(e for e in self.events if e.start < n))


def _type_name(t: type | tuple[type, ...]) -> str:
    if isinstance(t, tuple):
        return "a number" if float in t else " or ".join(x.__name__ for x in t)
    return {
        str: "a string",
        int: "an integer",
        bool: "true or false",
        list: "a list",
        float: "a number",
        dict: "a table",
    }.get(t, t.__name__)


def _check_type(where: str, key: str, value: Any, expected: type | tuple[type, ...]) -> None:
    types = expected if isinstance(expected, tuple) else (expected,)
    ok = isinstance(value, types) and not (isinstance(value, bool) and bool not in types)
    if not ok:
        raise ValueError(f"{where}: {key} must be {_type_name(expected)}, got {value!r}")


def _suggest(key: str, known: list[str]) -> str:
    import difflib

    close = difflib.get_close_matches(key, known, n=1)
    return f" (did you mean {close[0]!r}?)" if close else f"; known: {', '.join(known)}"


def spec_from_dict(data: Any, source: str = "<spec>") -> SequenceSpec:
    """Validate a parsed spec mapping; errors read ``source: field ... got value``."""
    where = source
    if not isinstance(data, dict):
        raise ValueError(f"{where}: a spec must be a table/mapping, got {type(data).__name__}")
    for key in data:
        if key not in TOP_FIELDS and key not in SECTIONS and key not in LISTS:
            raise ValueError(
                f"{where}: unknown field {key!r}"
                f"{_suggest(str(key), list(TOP_FIELDS) + list(SECTIONS) + list(LISTS))}"
            )
    for key, (typ, required) in TOP_FIELDS.items():
        if key not in data:
            if required:
                raise ValueError(f"{where}: missing required field {key!r}")
            continue
        _check_type(where, key, data[key], typ)
    name = data["name"]
    if not NAME_RE.match(name):
        raise ValueError(
            f"{where}: name must be letters, digits, '.', '-' or '_' (a folder name), got {name!r}"
        )
    if name.lower() in RESERVED_NAMES:
        raise ValueError(
            f"{where}: name {name!r} is the name of a file the sequences' folder holds "
            f"({', '.join(RESERVED_NAMES)}); choose another"
        )
    if data["seed"] < 0:
        raise ValueError(f"{where}: seed must be >= 0, got {data['seed']!r}")
    if not (1 <= data["frames"] <= MAX_FRAMES):
        raise ValueError(f"{where}: frames must be in [1, {MAX_FRAMES}], got {data['frames']!r}")
    fps = float(data.get("fps", 25.0))
    if not (MIN_FPS <= fps <= 1000):  # the simulation steps 1 / fps s, at most 0.2 s
        raise ValueError(f"{where}: fps must be in [{MIN_FPS:g}, 1000], got {data.get('fps')!r}")
    warmup = data.get("warmup_steps", 0)
    if not 0 <= warmup <= MAX_WARMUP_STEPS:  # 1e5 steps = 67 simulated minutes at 25 fps
        raise ValueError(
            f"{where}: warmup_steps must be in [0, {MAX_WARMUP_STEPS}], got {warmup!r}"
        )
    sections = {}
    for sec in SECTIONS:
        value = data.get(sec, {})
        if not isinstance(value, dict):
            raise ValueError(f"{where}: {sec} must be a table, got {value!r}")
        sections[sec] = dict(value)

    scenario = sections["scenario"]
    if "name" not in scenario:
        raise ValueError(f"{where}: missing required field 'scenario.name'")
    _check_type(where, "scenario.name", scenario["name"], str)
    built = _validate_scenario(where, scenario)

    camera = sections["camera"]
    for key, value in camera.items():
        if key not in CAMERA_FIELDS:
            raise ValueError(
                f"{where}: unknown field 'camera.{key}'{_suggest(key, list(CAMERA_FIELDS))}"
            )
        _check_type(where, f"camera.{key}", value, CAMERA_FIELDS[key])
    if ("width" in camera) != ("height" in camera):
        given = "width" if "width" in camera else "height"
        raise ValueError(
            f"{where}: camera.{given} needs camera.{'height' if given == 'width' else 'width'} "
            f"(give both or neither), got camera.{given} = {camera[given]!r} alone"
        )
    if "center" in camera:
        c = camera["center"]
        if len(c) != 2 or not all(
            isinstance(v, (int, float)) and not isinstance(v, bool) for v in c
        ):
            raise ValueError(f"{where}: camera.center must be two numbers, got {c!r}")
    # the same limits as crowdsim render: one 8192 x 8192 frame peaks at 3 GiB while drawn;
    # beyond 1e4 px/m a person is a millimetre wide and no head lands in the frame
    for key in ("max_width", "max_height", "width", "height"):
        if key in camera and not (8 <= camera[key] <= MAX_SIDE_PX):
            raise ValueError(
                f"{where}: camera.{key} must be in [8, {MAX_SIDE_PX}], got {camera[key]!r}"
            )
    if "px_per_m" in camera and not (
        math.isfinite(camera["px_per_m"]) and PX_PER_M[0] <= camera["px_per_m"] <= PX_PER_M[1]
    ):
        raise ValueError(
            f"{where}: camera.px_per_m must be in [{PX_PER_M[0]:g}, "
            f"{PX_PER_M[1]:g}], got {camera['px_per_m']:g}"
        )
    if "margin_m" in camera and not (0 <= camera["margin_m"] <= 1000):
        raise ValueError(
            f"{where}: camera.margin_m must be in [0, 1000], got {camera['margin_m']!r}"
        )
    from crowdsim.camera import Camera, motion_values

    try:  # range checks of the camera itself, with placeholders for the fitted fields
        Camera(
            px_per_m=float(camera.get("px_per_m", 10.0)),
            width=camera.get("width", 64),
            height=camera.get("height", 64),
            center=tuple(camera.get("center", (0.0, 0.0))),
            tilt_deg=float(camera.get("tilt_deg", 0.0)),
            distance_m=float(camera.get("distance_m", 60.0)),
            **motion_values(camera),
            ground_margin_px=camera.get("ground_margin_px", 0),
        )
    except ValueError as exc:
        raise ValueError(f"{where}: {exc}") from None

    app = sections["appearance"]
    known = list(AppearanceParams.__dataclass_fields__)
    for key, value in app.items():
        if key not in known:
            raise ValueError(f"{where}: unknown field 'appearance.{key}'{_suggest(key, known)}")
        default = AppearanceParams.__dataclass_fields__[key].default
        expected: type | tuple[type, ...]
        if isinstance(default, bool):
            expected = bool
        elif isinstance(default, int):
            expected = int
        elif isinstance(default, float):
            expected = (int, float)
        elif isinstance(default, str):
            expected = str
        else:
            expected = list
        _check_type(where, f"appearance.{key}", value, expected)
    try:
        appearance = AppearanceParams.from_dict(app)
    except ValueError as exc:
        raise ValueError(f"{where}: {exc}") from None

    output = {"images": True, "video": False}
    for key, value in sections["output"].items():
        if key not in OUTPUT_FIELDS:
            raise ValueError(
                f"{where}: unknown field 'output.{key}'{_suggest(key, list(OUTPUT_FIELDS))}"
            )
        _check_type(where, f"output.{key}", value, OUTPUT_FIELDS[key])
        output[key] = value
    if not (output["images"] or output["video"]):
        raise ValueError(f"{where}: output.images and output.video cannot both be false")
    if output["video"] or appearance.video_kbps > 0:  # video codecs take even sizes only
        for key in ("width", "height", "max_width", "max_height"):
            if key in camera and int(camera[key]) % 2:
                raise ValueError(
                    f"{where}: camera.{key} must be even for a video (output.video or "
                    f"appearance.video_kbps), got {camera[key]}"
                )

    for key, value in sections["calibration"].items():
        if not isinstance(value, (int, float, str, bool, list)):
            raise ValueError(
                f"{where}: calibration.{key} must be a number, string or list, got {value!r}"
            )
    events = parse_events(data.get("events"), where, n_frames=int(data["frames"]))
    if any(e.kind == "surge" for e in events) and not _has_inflow(built):
        raise ValueError(
            f"{where}: events: a surge multiplies the inflow, and scenario "
            f"{scenario['name']!r} with these parameters has none"
        )
    return SequenceSpec(
        name=name,
        seed=int(data["seed"]),
        frames=int(data["frames"]),
        fps=fps,
        warmup_steps=int(warmup),
        scenario=scenario,
        camera=camera,
        appearance=appearance,
        output=output,
        events=events,
        calibration=sections["calibration"],
        description=data.get("description", ""),
        source=source,
    )


def _has_inflow(scenario: Any) -> bool:
    """Whether ``scenario`` (a validated :class:`crowdsim.scenarios.Scenario`) has sources:
    its set-up with one agent."""
    from dataclasses import replace as with_fields

    import numpy as np

    one = with_fields(scenario, n_agents=1)
    return bool(one.build(np.random.default_rng(0)).sources)


def _validate_scenario(where: str, scenario: dict[str, Any]) -> Any:
    """The scenario of a spec's ``[scenario]`` table, built (its checks run); errors name
    ``where``."""
    from crowdsim.scenarios import make_scenario

    params = {k: v for k, v in scenario.items() if k != "name"}
    try:
        return make_scenario(scenario["name"], **params)
    except (ValueError, TypeError) as exc:
        raise ValueError(f"{where}: scenario: {exc}") from None


def parse_spec_text(text: str, fmt: str, source: str) -> Any:
    """Parse TOML (``fmt="toml"``) or YAML text; syntax errors name the source."""
    if fmt == "toml":
        if sys.version_info >= (3, 11):
            import tomllib
        else:  # pragma: no cover
            import tomli as tomllib
        try:
            return tomllib.loads(text)
        except tomllib.TOMLDecodeError as exc:
            raise ValueError(f"{source}: invalid TOML: {exc}") from None
    import yaml

    try:
        return yaml.load(text, Loader=_unique_key_loader())  # noqa: S506 - a SafeLoader
    except yaml.YAMLError as exc:
        raise ValueError(f"{source}: invalid YAML: {_yaml_problem(exc)}") from None


def _yaml_problem(exc: Any) -> str:
    """PyYAML's error as one line: what it found and where (``line 5, column 1``)."""
    problem = getattr(exc, "problem", None)
    mark = getattr(exc, "problem_mark", None)
    if problem is None:
        return " ".join(str(exc).split())
    where = f" (line {mark.line + 1}, column {mark.column + 1})" if mark is not None else ""
    context = getattr(exc, "context", None)
    return f"{context + ': ' if context else ''}{problem}{where}"


@functools.cache
def _unique_key_loader() -> type:
    """A ``yaml.SafeLoader`` that refuses a key given twice in one mapping (PyYAML keeps the
    last one in silence: ``name: a`` then ``name: b`` made sequence ``b``)."""
    import yaml

    class Loader(yaml.SafeLoader):
        pass

    def mapping(loader: Any, node: Any, deep: bool = False) -> dict[Any, Any]:
        seen = set()
        for key_node, _ in node.value:
            if key_node.tag == "tag:yaml.org,2002:merge":  # '<<: *anchor': SafeLoader merges it
                continue
            key = loader.construct_object(key_node, deep=deep)
            if key in seen:
                mark = key_node.start_mark
                raise yaml.constructor.ConstructorError(
                    None, None, f"key {key!r} is given twice", mark
                )
            seen.add(key)
        return loader.construct_mapping(node, deep=deep)

    Loader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG, mapping)
    return Loader


def load_spec(path: str | os.PathLike[str]) -> SequenceSpec:
    """Read and validate a ``.toml``, ``.yaml`` or ``.yml`` spec file."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in (".toml", ".yaml", ".yml"):
        raise ValueError(f"{path}: spec files must end in .toml, .yaml or .yml")
    try:
        text = path.read_text()
    except FileNotFoundError:
        raise ValueError(f"{path}: no such spec file") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ValueError(f"{path}: cannot read spec file ({exc})") from None
    data = parse_spec_text(text, "toml" if suffix == ".toml" else "yaml", str(path))
    return spec_from_dict(data, source=str(path))
