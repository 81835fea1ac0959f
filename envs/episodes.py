"""Where the tuning environments' episodes come from: one episode is one sequence.

Two sources, one face (:class:`EpisodeSource`):

* :class:`ScenarioEpisodes` -- a seeded **scenario distribution**
  (:class:`ScenarioDistribution`): each episode draws a scenario (marathon, counterflow,
  crossing, ...), a crowd size, a density, a template size and the appearance difficulty knobs
  (contrast, noise, colour clusters), builds a :class:`synth_data.spec.SequenceSpec` and
  simulates and renders it **in memory** (no disk), through the same video codec and JPEG
  steps as ``crowdsim generate`` (:func:`synth_data.video.camera_output`);
* :class:`SuiteEpisodes` -- the sequences of a **suite**: a built-in suite name
  (``ucf9``, ``galleria``: specs rendered in memory, optionally re-seeded) or a folder of MOT
  sequences written by ``crowdsim generate`` (each sub-folder one episode), ``only`` some of
  them.

With ``events`` (``--scenarios nonstationary``) every episode of a distribution gets one
scheduled change part-way through -- a lighting change, a noise or shake burst, the crowd
stopping, a surge of arrivals (:mod:`crowdsim.events`) -- and its family is the event's kind:
scenes where the best setting changes within a sequence.

:class:`EpisodeCache` keeps rendered episodes on disk (``--episode-cache DIR``): each is
simulated, rendered and encoded once, stored as the JPEG bytes of its frames with its ground
truth and checksums, and read back (checked) by every reset, epoch and process; a damaged
entry is moved aside and rendered again, never trusted.

``source.sample(rng)`` draws a random episode with the caller's generator (the environment's
``np_random``: every random choice comes from it); ``source.episode(i)`` is the ``i``-th
episode of a fixed, seeded list (what tuners score every trial on, and what held-out
evaluation uses with another ``seed``).

Sequences have the sequence face the tracker runner reads (``name, frame_rate, width, height,
length, template_size, frames(), gt_points(), births()``).
"""

from __future__ import annotations

import functools
import hashlib
import io
import json
import os
import sys
import time
import zipfile
from abc import ABC, abstractmethod
from collections import OrderedDict
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from crowdsim.atomic import hash_sources
from crowdsim.checks import require_number, require_sequences

DEFAULT_SCENARIOS: tuple[str, ...] = (
    "marathon",
    "counterflow",
    "crossing",
    "commuters",
    "groups",
    "circulation",
    "station",
    "anomalies",
)
"""Scenario families of the default distribution (``--scenarios all``): every scenario of
:mod:`crowdsim.scenarios`, in a fixed order, which the draws depend on. A new scenario is
appended here by hand (a test fails until it is), so every earlier draw stays the same."""


EVENT_STRENGTHS: dict[str, tuple[float, float]] = {
    "lighting": (0.3, 0.6),
    "noise": (15.0, 30.0),
    "shake": (3.0, 8.0),
    "stop": (0.6, 1.0),
    "surge": (3.0, 8.0),
}
"""Event kind -> the range its strength is drawn from in a non-stationary distribution:
a cloud or lights dimmed to 30-60 %; gain noise of sigma 15-30 grey levels; a shake of 3-8 px
(a gust on a mast); 60-100 % of the crowd stopping; inflow 3-8 times its rate (a train
arriving)."""
INFLOW_SCENARIOS: tuple[str, ...] = ("marathon", "counterflow", "commuters", "anomalies", "station")
"""Scenarios whose people arrive through inflows (what ``surge`` multiplies)."""
NONSTATIONARY: dict[str, Any] = {
    "scenarios": list(INFLOW_SCENARIOS),
    "events": list(EVENT_STRENGTHS),
}
"""``--scenarios nonstationary``: every event kind over the scenarios with inflow."""


def tiny_scenarios() -> dict[str, Any]:
    """A fresh ``scenarios=`` mapping for smoke runs and tests: 6-8 people of one family in 12
    frames of 160 x 120 px, so that an env step takes milliseconds.

    >>> ScenarioDistribution.from_dict(tiny_scenarios()).frames
    12
    """
    return {
        "scenarios": ["counterflow"],
        "agents": [6, 8],
        "frames": 12,
        "warmup_steps": 4,
        "template_px": [10],
        "max_width": 160,
        "max_height": 120,
    }


def _pair(
    owner: str, name: str, value: Any, *, lo: float, hi: float | None = None, integer: bool = False
) -> tuple[Any, Any]:
    if not (isinstance(value, (tuple, list)) and len(value) == 2):
        raise ValueError(f"{owner}.{name} must be a (low, high) pair, got {value!r}")
    for v in value:
        require_number(owner, name, v, lo=lo, hi=hi, integer=integer)
    if value[0] > value[1]:
        raise ValueError(f"{owner}.{name} must have low <= high, got {tuple(value)!r}")
    return (value[0], value[1])


@dataclass(frozen=True, kw_only=True)
class ScenarioDistribution:
    """A seeded distribution of small synthetic sequences (one per episode).

    Attributes
    ----------
    scenarios : tuple of str
        Scenario families drawn uniformly (names of :data:`crowdsim.scenarios.SCENARIOS`).
    agents : (int, int)
        Number of simulated people, uniform integer in ``[low, high]``.
    density_scale : (float, float)
        Factor (uniform) on the scenario's own default density (each family has a typical
        density: marathon 2.5 /m^2, station 0.5 /m^2).
    template_px : tuple of int
        Head sizes drawn uniformly, px (the papers' sequences: 8-16).
    frames : int
        Frames per sequence (one simulation step of ``1 / fps`` s each).
    warmup_steps : int
        Simulated steps dropped before the first frame (the crowd gets moving).
    fps : float
        Frame rate.
    contrast : (float, float)
        Renderer contrast of the people against the ground (lower = harder), uniform.
    noise_sigma : (float, float)
        Sensor noise, grey levels, uniform.
    n_clusters : (int, int)
        Number of clothing colour clusters (fewer = more people look alike), uniform integer.
    cluster_spread : (float, float)
        Colour spread inside a cluster (smaller = more alike), uniform.
    max_width, max_height : int
        Largest frame, px: the camera frames the crowd at the template's scale up to this size
        (small frames keep episodes fast).
    events : tuple of str
        Non-stationary families (kinds of :mod:`crowdsim.events`: ``lighting``, ``noise``,
        ``shake``, ``stop``, ``surge``): when given, every episode gets one event of a kind
        drawn uniformly, starting between a quarter and a half of the way in and lasting a
        quarter to a half of the frames, of a strength drawn from :data:`EVENT_STRENGTHS`.
        The episode's family is then the event's kind (:meth:`family`), so held-out scores
        and headroom come per kind. ``surge`` needs scenarios with inflow
        (:data:`INFLOW_SCENARIOS`).
    difficulty : (float, float)
        The calibration's difficulty scale (:func:`crowdsim.knobs.knob_values`: look-alike
        heads, packed bodies, gait and head turns, clutter, camera noise, blur, shake, JPEG
        and H.264 compression), uniform. The default spans the calibrated ucf9 suite (0.23 to
        0.89: sequences on which the NCC tracker scores the papers' 33-86 %).

    The default appearance knobs are harder than the renderer's defaults (low contrast, strong
    noise, few colour clusters, the calibrated difficulty): on the renderer's defaults every
    parameter setting tracks nearly 100 % of the points at 5 px and there is nothing to tune.
    """

    scenarios: tuple[str, ...] = DEFAULT_SCENARIOS
    agents: tuple[int, int] = (40, 100)
    density_scale: tuple[float, float] = (0.9, 1.4)
    template_px: tuple[int, ...] = (10, 12, 14)
    frames: int = 100
    warmup_steps: int = 25
    fps: float = 25.0
    contrast: tuple[float, float] = (0.25, 0.6)
    noise_sigma: tuple[float, float] = (4.0, 10.0)
    n_clusters: tuple[int, int] = (1, 3)
    cluster_spread: tuple[float, float] = (2.0, 8.0)
    max_width: int = 640
    max_height: int = 480
    difficulty: tuple[float, float] = (0.2, 0.9)
    events: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        from crowdsim.scenarios import MAX_AGENTS, SCENARIOS
        from synth_data.spec import MAX_FRAMES, MAX_SIDE_PX, MAX_WARMUP_STEPS

        own = "ScenarioDistribution"
        # one name is a family of one (tuple("marathon") would be its letters)
        scen = (self.scenarios,) if isinstance(self.scenarios, str) else self.scenarios
        if not isinstance(scen, (tuple, list)):
            raise ValueError(
                f"{own}.scenarios must be a scenario name or a list of them, got {scen!r}"
            )
        scen = tuple(scen)
        if not scen:
            raise ValueError(f"{own}.scenarios must name at least one scenario")
        for s in scen:
            if not isinstance(s, str) or s not in SCENARIOS:
                raise ValueError(f"unknown scenario {s!r}; valid scenarios: {', '.join(SCENARIOS)}")
        object.__setattr__(self, "scenarios", scen)
        object.__setattr__(
            self,
            "agents",
            _pair(own, "agents", self.agents, lo=1, hi=MAX_AGENTS, integer=True),
        )
        object.__setattr__(
            self, "density_scale", _pair(own, "density_scale", self.density_scale, lo=0.05, hi=5)
        )
        object.__setattr__(self, "contrast", _pair(own, "contrast", self.contrast, lo=0.05, hi=1.0))
        object.__setattr__(
            self, "noise_sigma", _pair(own, "noise_sigma", self.noise_sigma, lo=0, hi=50)
        )
        object.__setattr__(
            self, "n_clusters", _pair(own, "n_clusters", self.n_clusters, lo=1, hi=12, integer=True)
        )
        object.__setattr__(
            self, "cluster_spread", _pair(own, "cluster_spread", self.cluster_spread, lo=0, hi=60)
        )
        object.__setattr__(
            self, "difficulty", _pair(own, "difficulty", self.difficulty, lo=0, hi=1)
        )
        kinds = (self.events,) if isinstance(self.events, str) else self.events
        if not isinstance(kinds, (tuple, list)):
            raise ValueError(f"{own}.events must be an event kind or a list of them, got {kinds!r}")
        for k in kinds:
            if k not in EVENT_STRENGTHS:
                raise ValueError(
                    f"{own}.events: unknown kind {k!r}; valid kinds: {', '.join(EVENT_STRENGTHS)}"
                )
        object.__setattr__(self, "events", tuple(dict.fromkeys(kinds)))
        if "surge" in self.events:
            dry = [s for s in scen if s not in INFLOW_SCENARIOS]
            if dry:
                raise ValueError(
                    f"{own}.events: surge needs scenarios with inflow "
                    f"({', '.join(INFLOW_SCENARIOS)}); {', '.join(dry)} has none"
                )
        tp = self.template_px
        tp = (tp,) if isinstance(tp, (int, float, np.integer, np.floating)) else tp
        if not isinstance(tp, (tuple, list)):
            raise ValueError(f"{own}.template_px must be a size or a list of sizes, got {tp!r}")
        tp = tuple(tp)
        if not tp:
            raise ValueError(f"{own}.template_px must list at least one size")
        for v in tp:
            require_number(own, "template_px", v, lo=4, hi=64, integer=True)
        object.__setattr__(self, "template_px", tp)
        require_number(own, "frames", self.frames, lo=2, hi=MAX_FRAMES, integer=True)
        require_number(
            own, "warmup_steps", self.warmup_steps, lo=0, hi=MAX_WARMUP_STEPS, integer=True
        )
        # whole numbers written as 100.0 or 1e2 in a file are the integers they mean
        object.__setattr__(self, "frames", int(self.frames))
        object.__setattr__(self, "warmup_steps", int(self.warmup_steps))
        # a spec's lowest frame rate: the simulation steps 1 / fps s, at most 0.2 s
        require_number(own, "fps", self.fps, lo=5, hi=240)
        require_number(own, "max_width", self.max_width, lo=32, hi=MAX_SIDE_PX, integer=True)
        require_number(own, "max_height", self.max_height, lo=32, hi=MAX_SIDE_PX, integer=True)

    @classmethod
    def from_arg(cls, text: str, **overrides: Any) -> ScenarioDistribution:
        """From a CLI value: ``all``, ``nonstationary`` (:data:`NONSTATIONARY`), a comma list
        of scenario names (``marathon,crossing``) or a JSON/TOML file of fields; ``overrides``
        (e.g. ``frames``) on top. Every problem of a file (binary, broken, unknown or
        out-of-range fields) is a ``ValueError`` naming it."""
        text = str(text).strip()
        p = Path(text)
        if p.suffix.lower() in (".json", ".toml") or p.is_file():
            if not p.is_file():
                raise ValueError(f"--scenarios: no such file {text!r}")
            return cls.from_dict(_read_table(p), where=str(p), **overrides)
        if text in ("", "all"):
            return cls(**overrides)
        if text == "nonstationary":
            return cls.from_dict(NONSTATIONARY, **overrides)
        return cls(scenarios=tuple(s.strip() for s in text.split(",") if s.strip()), **overrides)

    @classmethod
    def from_dict(
        cls, data: Mapping[str, Any], where: str = "ScenarioDistribution", **overrides: Any
    ) -> ScenarioDistribution:
        """From a mapping of fields (lists for the pairs are fine); unknown or bad fields
        raise ``ValueError`` prefixed with ``where`` (the file they came from)."""
        if not isinstance(data, Mapping):
            raise ValueError(f"{where}: expected a table of distribution fields, got {data!r}")
        valid = set(cls.__dataclass_fields__)
        unknown = sorted(str(k) for k in set(data) - valid)
        if unknown:
            raise ValueError(
                f"{where}: unknown field(s) {', '.join(unknown)}; valid: {', '.join(sorted(valid))}"
            )
        fields = {k: tuple(v) if isinstance(v, list) else v for k, v in data.items()}
        try:
            return cls(**{**fields, **overrides})
        except ValueError as exc:
            if where == "ScenarioDistribution":
                raise
            raise ValueError(f"{where}: {exc}") from None

    def to_dict(self) -> dict[str, Any]:
        return {k: list(v) if isinstance(v, tuple) else v for k, v in asdict(self).items()}

    @property
    def families(self) -> tuple[str, ...]:
        """The families episodes are grouped by: the event kinds when there are any, else
        the scenarios."""
        return self.events or self.scenarios

    def family(self, spec: Any) -> str:
        """The family of one of this distribution's specs (:attr:`families`)."""
        if self.events and spec.events:
            return str(spec.events[0].kind)
        return str(spec.scenario["name"])

    def sample_spec(self, rng: np.random.Generator, name: str = "episode") -> Any:
        """Draw one :class:`~synth_data.spec.SequenceSpec` (all choices from ``rng``)."""
        from crowdsim.appearance_model import AppearanceParams
        from crowdsim.scenarios import SCENARIOS
        from synth_data.spec import SequenceSpec

        scen = self.scenarios[int(rng.integers(len(self.scenarios)))]
        n = int(rng.integers(self.agents[0], self.agents[1] + 1))
        base_density = float(SCENARIOS[scen].density)
        density = float(np.clip(base_density * rng.uniform(*self.density_scale), 0.05, 5.5))
        template = int(self.template_px[int(rng.integers(len(self.template_px)))])
        appearance = AppearanceParams(
            template_px=template,
            contrast=round(float(rng.uniform(*self.contrast)), 3),
            noise_sigma=round(float(rng.uniform(*self.noise_sigma)), 3),
            n_clusters=int(rng.integers(self.n_clusters[0], self.n_clusters[1] + 1)),
            cluster_spread=round(float(rng.uniform(*self.cluster_spread)), 3),
        )
        seed = int(rng.integers(2**31 - 1))
        d = round(float(rng.uniform(*self.difficulty)), 3)
        spec = SequenceSpec(
            name=name,
            seed=seed,
            frames=self.frames,
            fps=float(self.fps),
            warmup_steps=self.warmup_steps,
            scenario={"name": scen, "n_agents": n, "density": round(density, 3)}
            # the station's route layout the tuning evidence was measured on (no draw: every
            # episode stays the same; crowdsim.scenarios.Station says what layout 2 mends)
            | ({"routes": 1} if scen == "station" else {}),
            camera={"max_width": self.max_width, "max_height": self.max_height},
            appearance=appearance,
            output={"images": True, "video": False},
            description=f"{scen}, {n} people at {density:.2f}/m^2, {template} px, difficulty {d:g}",
        )
        if self.events:  # drawn last: distributions without events draw as before
            from crowdsim.events import Event

            kind = self.events[int(rng.integers(len(self.events)))]
            lo, hi = EVENT_STRENGTHS[kind]
            q = self.frames // 4
            start = int(rng.integers(q, max(q, self.frames // 2) + 1))
            length = int(rng.integers(max(1, q), max(1, 2 * q) + 1))
            ev = Event(kind, start, length, round(float(rng.uniform(lo, hi)), 3))
            spec = replace(
                spec,
                events=(ev,),
                description=f"{spec.description}; {kind} x{ev.magnitude:g} "
                f"at frames {start}-{start + length - 1}",
            )
        if d <= 0:
            return spec
        from crowdsim.knobs import apply_knobs, knob_values

        return apply_knobs(spec, knob_values(spec, d, d))


def _read_table(p: Path) -> dict[str, Any]:
    """The table of a JSON or TOML distribution file (by suffix; JSON otherwise)."""
    raw = p.read_bytes()
    kind = "TOML" if p.suffix.lower() == ".toml" else "JSON"
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError:
        raise ValueError(f"{p}: not a {kind} distribution file (binary, not UTF-8)") from None
    try:
        if kind == "TOML":
            if sys.version_info >= (3, 11):
                import tomllib
            else:  # pragma: no cover - Python 3.10 (pyproject installs tomli there)
                import tomli as tomllib

            data = tomllib.loads(text)
        else:
            data = json.loads(text)
    except ValueError as exc:  # json.JSONDecodeError and tomllib.TOMLDecodeError
        raise ValueError(f"{p}: not valid {kind} ({exc})") from None
    if not isinstance(data, dict):
        raise ValueError(f"{p}: expected a table of distribution fields")
    return data


# ---------------------------------------------------------------------------- sequences
def spec_sequence(spec: Any, cache_frames: bool = False, store: EpisodeCache | None = None) -> Any:
    """``spec`` simulated and rendered in memory (:class:`synth_data.sequence.InMemorySequence`;
    frames drawn on demand, or all rendered now and kept with ``cache_frames``), or read from
    the episode cache ``store`` (rendered and stored there first when it is not in it).

    The frames pass through the spec's video codec and JPEG steps in memory, so an episode
    shows the tracker what ``crowdsim generate`` then ``crowdsim track`` would (the tuned
    parameters meet the compression artefacts they will be scored on); a cached episode has
    the same frames, decoded from the same JPEG bytes."""
    from synth_data.sequence import InMemorySequence

    if store is not None:
        seq = store.sequence(spec)
    else:
        seq = InMemorySequence.from_spec(spec, camera_output=True)
    return seq.materialize() if cache_frames else seq


def folder_sequence(path: str | os.PathLike[str], frames: int | None = None) -> Any:
    """A MOT sequence folder with the sequence face (first ``frames`` frames only), checked
    first (:func:`verify_folder`): a damaged frame is named, never tracked."""
    from synth_data.sequence import open_sequence

    seq = open_sequence(path)
    verify_folder(seq)
    if frames is not None and frames < seq.length:
        seq = _Truncated(seq, frames)
    return seq


def mot_folders(path: str | os.PathLike[str], only: Sequence[str] | None = None) -> list[Path]:
    """The MOT sequence folders of ``path``: ``[path]`` when it is one itself (it has a
    ``seqinfo.ini``), else its sub-folders that have one, sorted by name; with ``only``, those
    named in it (``--only``). Raises ``ValueError`` naming ``path`` when there is none, and
    naming an ``only`` name it does not hold (what ``tune``, ``heldout`` and
    ``compare --sequences`` read). Hidden sub-folders are not sequences: ``generate``'s
    half-written ones (``.crowdsim-tmp-*``), and the old ones an ``--overwrite`` renamed
    aside, were tracked as sequences of their own while a ``generate`` ran (or after a kill)."""
    path = Path(path)
    if (path / "seqinfo.ini").is_file():
        folders = [path]
    else:
        folders = sorted(
            p
            for p in path.iterdir()
            if not p.name.startswith(".") and (p / "seqinfo.ini").is_file()
        )
        if not folders:
            raise ValueError(f"{path}: no MOT sequence folders (sub-folders with seqinfo.ini)")
    if only:
        require_sequences("--only", only, [p.name for p in folders], str(path))
        folders = [p for p in folders if p.name in only]
    return folders


_JPEG_EOI_WINDOW = 64
"""Bytes at the end of a JPEG searched for its end-of-image marker ``FF D9`` (encoders may
pad after it; inside the entropy-coded data ``FF`` is never followed by ``D9``)."""


def image_is_complete(path: Path) -> bool:
    """Whether a JPEG or PNG file holds a whole image: its start marker and its end marker
    (JPEG ``FF D9``, PNG ``IEND``) are there. A truncated JPEG decodes without an error in
    OpenCV (the missing rows come out grey), so the markers are the evidence. Other formats
    are left to the decoder (``True``)."""
    suffix = path.suffix.lower()
    if suffix not in (".jpg", ".jpeg", ".png"):
        return True
    with open(path, "rb") as fh:
        head = fh.read(8)
        fh.seek(0, os.SEEK_END)
        size = fh.tell()
        fh.seek(max(0, size - _JPEG_EOI_WINDOW))
        tail = fh.read()
    if suffix == ".png":
        return head == b"\x89PNG\r\n\x1a\n" and b"IEND" in tail[-16:]
    return head[:2] == b"\xff\xd8" and b"\xff\xd9" in tail


def verify_folder(seq: Any) -> None:
    """Refuse a damaged MOT sequence folder, naming the file (``ValueError``).

    What ``crowdsim track`` checks (:func:`synth_data.mot.verify_frames`: every file of
    ``checksums.json`` matches its SHA-256; without one, every promised image is there and the
    first decodes at the ``seqinfo.ini`` size), and without ``checksums.json`` every JPEG or
    PNG frame is complete (:func:`image_is_complete`): a frame that cannot decode is an error
    naming it, never a grey block tracked silently.
    """
    from synth_data.mot import CHECKSUMS_FILE, verify_frames

    verify_frames(seq)
    im_dir = seq.path / seq.im_dir
    if (seq.path / CHECKSUMS_FILE).is_file() or not im_dir.is_dir():
        return
    for i in range(1, seq.length + 1):
        p = im_dir / f"{i:06d}{seq.im_ext}"
        if not image_is_complete(p):
            raise ValueError(f"{p}: not a complete image (truncated or damaged; cannot decode)")


class _Cache:
    """A small LRU of built sequences (index -> sequence)."""

    def __init__(self, size: int) -> None:
        self.size = int(size)
        self.items: OrderedDict[Any, Any] = OrderedDict()

    def get(self, key: Any, build: Any) -> Any:
        if self.size <= 0:
            return build()
        if key in self.items:
            self.items.move_to_end(key)
            return self.items[key]
        value = build()
        self.items[key] = value
        while len(self.items) > self.size:
            self.items.popitem(last=False)
        return value


# ---------------------------------------------------------------------------- episode cache
EPISODE_FORMAT = "crowdsim-episode"
"""The ``format`` tag of an episode cache entry's ``episode.json``."""

EPISODE_FORMAT_VERSION = 1

_ENTRY_META = "episode.json"
_ENTRY_FILES = ("frames.bin", "truth.npz")
"""An entry's checksummed files: the JPEG file of every frame, back to back (``frames.bin``),
and ``truth.npz`` (``offsets`` into it, ground-truth ``ids`` and ``points``)."""

DAMAGED_DIR = "damaged"
"""Sub-folder of the cache where a damaged entry is moved (never deleted, never trusted)."""


@functools.cache
def code_digest() -> str:
    """SHA-256 of what makes an episode's frames: the source of ``crowdsim``'s and
    ``synth_data``'s top-level modules (not their sub-packages), and the versions of numpy,
    OpenCV (its JPEG), pymunk, numba (the force kernels), SciPy (the spawn's k-d trees) and
    PyAV (its libx264 makes the H.264 bytes). An entry made by other code is another key, so
    an upgrade never reads a stale episode."""
    from importlib import metadata

    import cv2
    import pymunk

    import crowdsim
    import synth_data

    h = hashlib.sha256()
    hash_sources(h, {pkg.__name__: Path(pkg.__file__).parent for pkg in (crowdsim, synth_data)})
    h.update(f"numpy {np.__version__} cv2 {cv2.__version__} pymunk {pymunk.version}".encode())
    for dist in ("numba", "scipy", "av"):
        try:
            version = metadata.version(dist)
        except metadata.PackageNotFoundError:  # PyAV is needed only to encode H.264
            version = "none"
        h.update(f" {dist} {version}".encode())
    return h.hexdigest()


def episode_key(spec: Any) -> str:
    """The cache key of a spec's episode: its :meth:`~synth_data.spec.SequenceSpec.digest`
    (everything that changes the frames), the entry format and :func:`code_digest`."""
    doc = [EPISODE_FORMAT, EPISODE_FORMAT_VERSION, spec.digest(), code_digest()]
    return hashlib.sha256(json.dumps(doc).encode()).hexdigest()[:40]


class _Damaged(Exception):
    """An entry that fails its checks (the message says which)."""


def _jpeg_sequence(meta: Mapping[str, Any], blob: bytes, truth: Mapping[str, np.ndarray]) -> Any:
    """The in-memory sequence of an entry: each frame decoded from its JPEG on demand, as
    :func:`synth_data.video.camera_output` decodes it (so the frames are the same)."""
    import cv2

    from synth_data.sequence import InMemorySequence

    offsets = truth["offsets"]
    buf = np.frombuffer(blob, np.uint8)

    def frame(t: int) -> np.ndarray:
        return cv2.imdecode(buf[offsets[t] : offsets[t + 1]], cv2.IMREAD_COLOR)

    return InMemorySequence(
        name=meta["name"],
        frame_rate=meta["frame_rate"],
        width=meta["width"],
        height=meta["height"],
        template_size=meta["template_size"],
        render=frame,
        length=len(offsets) - 1,
        ids=truth["ids"],
        points=truth["points"],
    )


def _sha256(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


class EpisodeCache:
    """Episodes rendered and encoded once, kept on disk and reused across resets, epochs and
    processes: a reset that hits the cache costs a file read and a checksum, not a simulation,
    a rendering and a video encoding.

    An entry is the folder ``ROOT/<key>`` (:func:`episode_key`) with ``episode.json`` (the
    spec, the frame geometry and the SHA-256 of the other two files), ``frames.bin`` (the
    JPEG file of every frame, exactly the bytes ``crowdsim generate`` writes to ``img1/``) and
    ``truth.npz``. Every load checks both checksums: a damaged entry is moved to
    ``ROOT/damaged/`` (never deleted: the program keeps whatever it cannot prove it made) and
    the episode is rendered again, never trusted. Entries are written into a temporary folder
    and renamed into place, so a killed process leaves no half-written entry, and two
    processes making the same episode keep one.

    Parameters
    ----------
    root : path
        The cache folder (made on the first store). Nothing else in it is touched.
    log : callable, optional
        ``log(message)`` for damaged entries (default: a warning on stderr).
    """

    def __init__(self, root: str | os.PathLike[str], log: Any = None) -> None:
        self.root = Path(root)
        if self.root.exists() and not self.root.is_dir():
            raise ValueError(f"episode cache {self.root}: not a folder")
        self.log = log or (lambda msg: print(msg, file=sys.stderr))
        self.hits = 0
        self.stores = 0
        self.damaged = 0

    def __repr__(self) -> str:
        return f"EpisodeCache({str(self.root)!r})"

    def entry(self, spec: Any) -> Path:
        """The folder of ``spec``'s entry (present or not)."""
        return self.root / episode_key(spec)

    def has(self, spec: Any) -> bool:
        """Whether an entry for ``spec`` is there (checked when it is loaded)."""
        return (self.entry(spec) / _ENTRY_META).is_file()

    def sequence(self, spec: Any) -> Any:
        """``spec``'s episode: loaded from its entry, or rendered, encoded and stored first."""
        seq = self.load(spec)
        return seq if seq is not None else self.store(spec)

    # -- load
    def load(self, spec: Any) -> Any:
        """``spec``'s episode from its entry, or ``None`` when there is none or it was damaged
        (then moved to ``damaged/``)."""
        path = self.entry(spec)
        if not path.exists():
            return None
        try:
            seq = self._read(path, spec)
        except _Damaged as exc:
            self._quarantine(path, str(exc))
            return None
        self.hits += 1
        return seq

    def _read(self, path: Path, spec: Any) -> Any:
        try:
            meta = json.loads((path / _ENTRY_META).read_text(encoding="utf-8"))
            blobs = {name: (path / name).read_bytes() for name in _ENTRY_FILES}
        except (OSError, UnicodeDecodeError, ValueError) as exc:
            raise _Damaged(f"unreadable: {exc}") from None
        if not isinstance(meta, dict) or meta.get("format") != EPISODE_FORMAT:
            raise _Damaged(f"{_ENTRY_META} is not a {EPISODE_FORMAT} record")
        if meta.get("version") != EPISODE_FORMAT_VERSION or meta.get("key") != path.name:
            raise _Damaged(f"{_ENTRY_META} names another format version or key")
        sums = meta.get("sha256")
        for name, blob in blobs.items():
            if not isinstance(sums, dict) or sums.get(name) != _sha256(blob):
                raise _Damaged(f"{name}: checksum mismatch")
        try:
            with np.load(io.BytesIO(blobs["truth.npz"]), allow_pickle=False) as z:
                truth = {k: z[k] for k in ("offsets", "ids", "points")}
            offsets = truth["offsets"]
            if (
                offsets.ndim != 1
                or len(offsets) != spec.frames + 1
                or offsets[0] != 0
                or offsets[-1] != len(blobs["frames.bin"])
                or (np.diff(offsets) <= 0).any()
            ):
                raise ValueError("frame offsets do not cover frames.bin")
            return _jpeg_sequence(meta, blobs["frames.bin"], truth)
        except (KeyError, ValueError, TypeError, zipfile.BadZipFile) as exc:
            raise _Damaged(f"inconsistent: {exc}") from None

    def _quarantine(self, path: Path, reason: str) -> None:
        self.damaged += 1
        dest = self.root / DAMAGED_DIR / f"{path.name}-{time.time_ns()}"
        dest.parent.mkdir(exist_ok=True)
        os.rename(path, dest)
        self.log(f"episode cache: {path} is damaged ({reason}); moved to {dest}; re-rendering")

    # -- store
    def store(self, spec: Any) -> Any:
        """Simulate, render and encode ``spec`` (the camera's codec and JPEG steps), write its
        entry atomically and return the episode."""
        import shutil
        import tempfile

        from synth_data.sequence import InMemorySequence
        from synth_data.video import encode_output

        raw = InMemorySequence.from_spec(spec)
        jpegs = list(encode_output(raw.frames(), spec.fps, spec.appearance.encoding))
        offsets = np.zeros(len(jpegs) + 1, np.int64)
        offsets[1:] = np.cumsum([len(j) for j in jpegs])
        blob = b"".join(jpegs)
        ids, points = raw.gt_points()
        truth = {"offsets": offsets, "ids": np.asarray(ids), "points": np.asarray(points)}
        npz = io.BytesIO()
        np.savez(npz, **truth)
        files = {"frames.bin": blob, "truth.npz": npz.getvalue()}
        path = self.entry(spec)
        meta = {
            "format": EPISODE_FORMAT,
            "version": EPISODE_FORMAT_VERSION,
            "key": path.name,
            "name": raw.name,
            "frame_rate": raw.frame_rate,
            "width": raw.width,
            "height": raw.height,
            "template_size": raw.template_size,
            "frames": raw.length,
            "sha256": {name: _sha256(b) for name, b in files.items()},
            "spec": spec.to_dict(),
        }
        self.root.mkdir(parents=True, exist_ok=True)
        tmp = Path(tempfile.mkdtemp(prefix=f".tmp-{path.name}-", dir=self.root))
        try:
            for name, data in files.items():
                (tmp / name).write_bytes(data)
            (tmp / _ENTRY_META).write_text(json.dumps(meta, indent=1), encoding="utf-8")
            try:
                os.rename(tmp, path)
            except OSError:
                if not path.exists():
                    raise
                shutil.rmtree(tmp)  # another process stored the same episode first
        except BaseException:
            shutil.rmtree(tmp, ignore_errors=True)
            raise
        self.stores += 1
        return _jpeg_sequence(meta, blob, truth)

    def fill(self, specs: Sequence[Any], workers: int = 1, progress: bool = True) -> dict[str, Any]:
        """Store every spec without an entry, over ``workers`` processes (a progress bar in
        frames); return ``{"episodes", "stored", "present", "wall_s"}``. Run before training,
        so that no environment renders while the others wait for it."""
        import tempfile

        from crowdsim.jobs import Job, one_numba_thread, run_jobs

        require_number("EpisodeCache.fill", "workers", workers, lo=1, integer=True)
        t0 = time.perf_counter()
        todo: dict[str, Any] = {}
        for spec in specs:
            if not self.has(spec):
                todo.setdefault(episode_key(spec), spec)
        jobs = [
            Job(key=k, fn=_store_one, args=(str(self.root), s), size=s.frames)
            for k, s in todo.items()
        ]
        if jobs:
            self.root.mkdir(parents=True, exist_ok=True)
            with tempfile.TemporaryDirectory() as tmp:
                run_jobs(
                    jobs,
                    Path(tmp) / "fill.json",
                    workers=workers,
                    progress=progress,
                    desc="episode cache",
                    unit="frame",
                    worker_init=one_numba_thread if workers > 1 else None,
                    passthrough=(ValueError, OSError, MemoryError),
                )
        return {
            "episodes": len(specs),
            "stored": len(jobs),
            "present": len(specs) - len(jobs),
            "wall_s": time.perf_counter() - t0,
        }


def _store_one(root: str, spec: Any) -> dict[str, Any]:
    """Pool job of :meth:`EpisodeCache.fill`: store one episode."""
    seq = EpisodeCache(root).store(spec)
    return {"name": seq.name, "frames": seq.length}


# ---------------------------------------------------------------------------- sources
def shows_someone(seq: Any) -> bool:
    """Whether the sequence ``seq`` has ground truth to score against: a distribution's
    camera can frame nobody (a few people in a wide hall), and such an episode is skipped
    by held-out scoring, tuning and the tuning env's draws alike."""
    return len(seq.gt_points()[0]) > 0


class EpisodeSource(ABC):
    """Where episodes come from: ``sample(rng)`` (random) or ``episode(i)`` (fixed list)."""

    @abstractmethod
    def spec(self, index: int) -> Any:
        """What episode ``index`` is (a spec, or a folder path)."""

    @abstractmethod
    def _build(self, index: int) -> Any:
        """Build episode ``index``'s sequence."""

    @abstractmethod
    def __len__(self) -> int:
        """Number of distinct episodes (a large number for a distribution)."""

    def __init__(self, cache: int = 0, store: EpisodeCache | None = None) -> None:
        self._cache = _Cache(cache)
        self.store = store

    def cached_specs(self) -> list[Any]:
        """The specs of every episode the source can give, where they are a finite list of
        specs (what :meth:`fill` stores); ``[]`` otherwise."""
        return []

    def fill(self, workers: int = 1, progress: bool = True) -> dict[str, Any] | None:
        """Store every episode of the source in its episode cache (:meth:`EpisodeCache.fill`)
        before use; ``None`` when the source has no cache."""
        if self.store is None:
            return None
        return self.store.fill(self.cached_specs(), workers=workers, progress=progress)

    def episode(self, index: int) -> Any:
        """Episode ``index`` (deterministic; the same sequence on every call), ``0 <= index <
        len(self)``: a suite's sequences, a pool's episodes, or a distribution's stream."""
        require_number(type(self).__name__, "index", index, lo=0, hi=len(self) - 1, integer=True)
        return self._cache.get(int(index), lambda: self._build(int(index)))

    def sample(self, rng: np.random.Generator) -> Any:
        """A random episode drawn with ``rng``."""
        return self.episode(int(rng.integers(len(self))))

    def describe(self) -> dict[str, Any]:
        return {"kind": type(self).__name__}


class ScenarioEpisodes(EpisodeSource):
    """Episodes from a :class:`ScenarioDistribution`; episode ``i`` of stream ``seed`` is
    drawn with ``default_rng(SeedSequence([seed, i]))``: different ``seed`` values give
    disjoint sequences (train on ``seed=0``, score on ``seed=1``).

    ``pool=N``: ``sample`` draws one of the first ``N`` episodes of the stream (each one
    reused across resets and epochs: what an episode cache ``store`` needs, and required with
    one); without a pool every sample is a new scene.
    """

    def __init__(
        self,
        dist: ScenarioDistribution | None = None,
        seed: int = 0,
        cache: int = 0,
        cache_frames: bool = False,
        store: EpisodeCache | None = None,
        pool: int | None = None,
    ) -> None:
        super().__init__(cache, store)
        require_number("ScenarioEpisodes", "seed", seed, lo=0, integer=True)
        if pool is not None:
            require_number("ScenarioEpisodes", "pool", pool, lo=1, integer=True)
        elif store is not None:
            raise ValueError(
                "ScenarioEpisodes: an episode cache needs pool=N, the number of distinct "
                "episodes to draw from and reuse (a scenario distribution is endless)"
            )
        self.dist = dist if dist is not None else ScenarioDistribution()
        self.seed = int(seed)
        self.cache_frames = bool(cache_frames)
        self.pool = None if pool is None else int(pool)

    def __len__(self) -> int:
        return 2**31 - 1 if self.pool is None else self.pool

    def cached_specs(self) -> list[Any]:
        return [self.spec(i) for i in range(self.pool or 0)]

    def spec(self, index: int) -> Any:
        rng = np.random.default_rng(np.random.SeedSequence([self.seed, int(index)]))
        return self.dist.sample_spec(rng, name=f"s{self.seed}-e{int(index)}")

    def _build(self, index: int) -> Any:
        return spec_sequence(self.spec(index), cache_frames=self.cache_frames, store=self.store)

    def sample(self, rng: np.random.Generator) -> Any:
        if self.pool is not None:
            return super().sample(rng)
        # drawn straight from the caller's generator (not via an index), so that every
        # choice of a random episode is the environment's np_random
        spec = self.dist.sample_spec(rng, name="episode")
        # named by what was drawn (info["sequence"]): the scenario and the scene's seed
        return spec_sequence(replace(spec, name=f"{spec.scenario['name']}-{spec.seed}"))

    def describe(self) -> dict[str, Any]:
        doc = {"kind": "scenarios", "seed": self.seed, "distribution": self.dist.to_dict()}
        if self.pool is not None:
            doc["pool"] = self.pool
        return doc


class SuiteEpisodes(EpisodeSource):
    """Episodes from a suite: a built-in suite name, a folder of spec files, or a folder of
    MOT sequence folders.

    Parameters
    ----------
    suite : str or path
        ``ucf9`` / ``galleria`` / ``stress`` or a folder of ``*.toml`` spec files such as
        ``crowdsim calibrate --out`` writes (specs simulated and rendered in memory;
        :func:`synth_data.suites.is_spec_suite`), or a folder whose sub-folders are MOT
        sequences (``crowdsim generate`` output), or one MOT sequence folder.
    only : sequence of str, optional
        Keep only these sequence names.
    frames : int, optional
        Use only the first ``frames`` frames of each sequence.
    reseed : int
        Spec suites only: add ``reseed`` to every spec's seed (another crowd and rendering
        of the same scene type: held-out scoring never sees a tuning seed).
    """

    def __init__(
        self,
        suite: str | os.PathLike[str],
        only: Sequence[str] | None = None,
        frames: int | None = None,
        reseed: int = 0,
        cache: int = 0,
        cache_frames: bool = False,
        store: EpisodeCache | None = None,
    ) -> None:
        super().__init__(cache, store)
        from synth_data.suites import SUITE_NAMES, is_spec_suite, suite_specs

        if frames is not None:
            require_number("SuiteEpisodes", "frames", frames, lo=2, integer=True)
        require_number("SuiteEpisodes", "reseed", reseed, lo=0, integer=True)
        self.suite = str(suite)
        self.frames = frames
        self.reseed = int(reseed)
        self.cache_frames = bool(cache_frames)
        only = [only] if isinstance(only, str) else (list(only) if only else None)
        if is_spec_suite(self.suite):
            specs = [s.truncated(frames) for s in suite_specs(self.suite, only)]
            self.items: list[Any] = [replace(s, seed=s.seed + self.reseed) for s in specs]
            self.on_disk = False
            return
        path = Path(self.suite)
        if not path.is_dir():
            raise ValueError(
                f"unknown suite {self.suite!r}: neither a built-in suite "
                f"({', '.join(SUITE_NAMES)}) nor a folder of spec files or of sequences"
            )
        if reseed:
            raise ValueError(
                "reseed applies to built-in suites only (a folder on disk has fixed sequences)"
            )
        folders = mot_folders(path, only)
        from synth_data.sequence import open_sequence

        for folder in folders:  # before any work: a damaged frame is named, not tracked
            verify_folder(open_sequence(folder))
        self.items = folders
        self.on_disk = True

    @classmethod
    def folder_names(cls, suite: str | os.PathLike[str]) -> list[str]:
        """Names of the sequences of a suite folder (without opening any)."""
        return [p.name for p in mot_folders(suite)]

    def __len__(self) -> int:
        return len(self.items)

    def spec(self, index: int) -> Any:
        return self.items[int(index) % len(self.items)]

    def cached_specs(self) -> list[Any]:
        return [] if self.on_disk else list(self.items)

    def _build(self, index: int) -> Any:
        item = self.spec(index)
        if not self.on_disk:
            return spec_sequence(item, cache_frames=self.cache_frames, store=self.store)
        seq = folder_sequence(item, self.frames)  # checked again: it may have changed since
        if self.cache_frames:
            from synth_data.sequence import InMemorySequence

            seq = InMemorySequence.from_source(seq)
        return seq

    def names(self) -> list[str]:
        return [p.name for p in self.items]

    def describe(self) -> dict[str, Any]:
        return {
            "kind": "suite",
            "suite": self.suite,
            "sequences": self.names(),
            "frames": self.frames,
            "reseed": self.reseed,
        }


class _Truncated:
    """The first ``n`` frames of a sequence (same face)."""

    def __init__(self, seq: Any, n: int) -> None:
        self._seq = seq
        self.length = int(n)
        for k in ("name", "frame_rate", "width", "height", "template_size"):
            setattr(self, k, getattr(seq, k))

    def frames(self) -> Iterator[np.ndarray]:
        import itertools

        return itertools.islice(self._seq.frames(), self.length)

    def gt_points(self) -> tuple[np.ndarray, np.ndarray]:
        ids, pts = self._seq.gt_points()
        return ids, pts[: self.length]

    def births(self) -> Any:
        init, births = self._seq.births()
        return init, {t: b for t, b in births.items() if t < self.length}


def make_episodes(
    suite: str | None = None,
    scenarios: str | ScenarioDistribution | None = None,
    *,
    only: Sequence[str] | None = None,
    frames: int | None = None,
    seed: int = 0,
    cache: int = 0,
    cache_frames: bool = False,
    overrides: Mapping[str, Any] | None = None,
    episode_cache: str | os.PathLike[str] | None = None,
    pool: int | None = None,
) -> EpisodeSource:
    """One source from the CLI's ``--suite NAME | --scenarios DIST [--only] [--frames]
    [--episode-cache DIR --pool N]``.

    ``seed`` selects the scenario stream (or, for a suite of specs, the ``reseed`` offset),
    so that tuning and held-out scoring draw disjoint sequences. ``episode_cache``: episodes
    of specs (scenario pools, suites of specs) are read from that :class:`EpisodeCache`
    folder, rendered and stored there on first use; ``pool`` (scenario distributions only,
    required with a cache): the number of distinct episodes drawn and reused.
    """
    if (suite is None) == (scenarios is None):
        raise ValueError("give exactly one of --suite NAME and --scenarios DIST")
    if frames is not None:  # 2.7 frames is a mistake, not 2
        require_number("", "frames", frames, lo=2, integer=True)
    store = None if episode_cache is None else EpisodeCache(episode_cache)
    if suite is not None:
        from synth_data.suites import is_spec_suite

        specs = is_spec_suite(suite)
        reseed = seed if specs else 0
        if seed and not specs:
            raise ValueError(
                f"{suite}: a folder of sequences cannot be re-seeded for held-out "
                "scoring; give held-out sequences with --only or another folder"
            )
        if pool is not None:
            raise ValueError("--pool draws from a scenario distribution; a suite has its sequences")
        return SuiteEpisodes(
            suite,
            only=only,
            frames=frames,
            reseed=reseed,
            cache=cache,
            cache_frames=cache_frames,
            store=store,
        )
    if only:
        raise ValueError(
            "--only selects sequences of a --suite, not scenarios "
            "(name the scenarios in --scenarios)"
        )
    extra = dict(overrides or {})
    if frames is not None:
        extra["frames"] = int(frames)
    dist = (
        scenarios
        if isinstance(scenarios, ScenarioDistribution)
        else ScenarioDistribution.from_arg(str(scenarios), **extra)
    )
    if isinstance(scenarios, ScenarioDistribution) and extra:
        dist = replace(dist, **extra)
    return ScenarioEpisodes(
        dist, seed=seed, cache=cache, cache_frames=cache_frames, store=store, pool=pool
    )
