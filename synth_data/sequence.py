"""One face for every sequence a tracker runs on: :class:`SequenceSource`.

Three implementations:

* a MOTChallenge folder: :class:`synth_data.mot.MotSequence` (``read_sequence(path)``);
* a video file: :class:`VideoSequence` (targets from a points CSV, no ground truth);
* frames in memory: :class:`InMemorySequence`, e.g. ``InMemorySequence.from_spec(spec)``
  (simulated and rendered without touching disk, through :mod:`synth_data.scene`) or
  :func:`synthetic_crowd` (the benchmarks' lanes of opposite flows).

:func:`open_sequence` opens a folder or a video by path. Births follow the papers: the
targets present in the first frame start the tracker, every later one is born at its first
frame, at its ground-truth position (or as listed in a points CSV, :mod:`synth_data.births`).

>>> seq = synthetic_crowd(3, 2, seed=0, size=(64, 48))
>>> isinstance(seq, SequenceSource), seq.length, next(seq.frames()).shape
(True, 2, (48, 64, 3))
>>> (ids0, pts0), later = seq.births()
>>> ids0.tolist(), pts0.shape
([1, 2, 3], (3, 2))
"""

from __future__ import annotations

import itertools
import math
import os
from collections.abc import Callable, Iterable, Iterator, Sequence
from pathlib import Path
from typing import Any, Protocol, runtime_checkable

import numpy as np

from crowdsim.checks import checked_ids, require_number
from synth_data.births import Births, births_from_ground_truth, births_from_init


@runtime_checkable
class SequenceSource(Protocol):
    """What a tracker runner needs from a sequence.

    Attributes
    ----------
    name : str
    frame_rate : float
        Frames per second.
    width, height : int
        Frame size in pixels.
    length : int
        Number of frames ``T``.
    template_size : int
        Head (template) size in pixels.
    """

    name: str
    frame_rate: float
    width: int
    height: int
    length: int
    template_size: int

    def frames(self) -> Iterator[np.ndarray]:
        """Every frame in order as ``(H, W, 3)`` uint8 BGR; may be called again."""
        ...

    def gt_points(self) -> tuple[np.ndarray, np.ndarray]:
        """``(ids (N,) int64, points (T, N, 2) float64 px)``, NaN where absent; ``N = 0``
        without ground truth."""
        ...

    def births(self) -> Births:
        """Targets to start at frame 0 and the later births (see :data:`Births`)."""
        ...


def _no_gt(length: int) -> tuple[np.ndarray, np.ndarray]:
    return np.zeros(0, np.int64), np.full((length, 0, 2), np.nan)


# ---------------------------------------------------------------------------- video
class VideoSequence:
    """Frames of a video file; targets from a points CSV (``init``), no ground truth.

    Parameters
    ----------
    path : path
        Any video OpenCV reads.
    init : path, optional
        Points CSV, needed by :meth:`births`: a header ``frame,id,x,y`` (1-based frames,
        pixel centres of the heads; frame 1 must list someone) or ``id,x,y`` (all in frame 1),
        read by :func:`synth_data.births.read_points_csv`.
    template_size : int, optional
        Head size in pixels (default :data:`synth_data.mot.DEFAULT_TEMPLATE_SIZE`).
    """

    def __init__(
        self,
        path: str | os.PathLike[str],
        init: str | os.PathLike[str] | None = None,
        template_size: int | None = None,
    ) -> None:
        import cv2

        from synth_data.mot import DEFAULT_TEMPLATE_SIZE

        path = Path(path)
        if not path.is_file():
            raise ValueError(f"{path}: no such video file")
        cap = cv2.VideoCapture(str(path))
        try:
            ok, first = cap.read() if cap.isOpened() else (False, None)
            if not ok:
                raise ValueError(f"{path}: not a readable video file")
            fps = float(cap.get(cv2.CAP_PROP_FPS) or 0.0)
            count = int(cap.get(cv2.CAP_PROP_FRAME_COUNT) or 0)
            if count <= 0:  # containers without a frame count: count them
                count = 1
                while cap.grab():
                    count += 1
        finally:
            cap.release()
        self.path = path
        self.init = None if init is None else Path(init)
        self.name = path.stem
        self.frame_rate = fps if math.isfinite(fps) and fps > 0 else 25.0
        self.height, self.width = (int(v) for v in first.shape[:2])
        self.length = count
        if template_size is None:
            template_size = DEFAULT_TEMPLATE_SIZE
        # checked as given: 0, 2.7 or "12" are refused, never turned into another size
        require_number(str(path), "template_size", template_size, lo=2, integer=True)
        self.template_size = int(template_size)

    def __repr__(self) -> str:
        return f"VideoSequence({str(self.path)!r}, {self.length} frames {self.width}x{self.height})"

    def frames(self) -> Iterator[np.ndarray]:
        """Every frame in order; a decoder that stops before :attr:`length` (a cut file) or
        still has frames after it (a header that under-counts) is reported as a
        :class:`crowdsim.checks.DataNote` warning, never in silence."""
        import warnings

        import cv2

        from crowdsim.checks import DataNote

        cap = cv2.VideoCapture(str(self.path))
        try:
            for i in range(self.length):
                ok, img = cap.read()
                if not ok:
                    warnings.warn(
                        f"{self.path}: the decoder gave {i} frames where the header counts "
                        f"{self.length}; the sequence ends at frame {i}",
                        DataNote,
                        stacklevel=2,
                    )
                    return
                # looked for before the last frame is handed over: a reader that takes
                # exactly ``length`` frames (itertools.islice) never resumes this generator
                if i == self.length - 1 and cap.grab():  # a count estimated from the duration
                    warnings.warn(
                        f"{self.path}: the video holds more frames than the {self.length} its "
                        "header counts (an estimate from its duration, as a variable frame "
                        "rate gives); the later ones are not read: convert it to MP4 to read "
                        "them all",
                        DataNote,
                        stacklevel=2,
                    )
                yield img
        finally:
            cap.release()

    def gt_points(self) -> tuple[np.ndarray, np.ndarray]:
        return _no_gt(self.length)

    def births(self) -> Births:
        if self.init is None:
            raise ValueError(
                f"{self.path}: a video has no ground truth to start from; give a "
                "points CSV (--init points.csv with rows frame,id,x,y), or start from the "
                "head detector (crowdsim track without --init)"
            )
        return births_from_init(self.init, self.length, where=str(self.path))


# ---------------------------------------------------------------------------- in memory
class InMemorySequence:
    """A sequence held in memory: a list of frames, or a renderer drawing them on demand.

    Parameters (keyword-only)
    -------------------------
    name : str
    frame_rate : float
    width, height : int
    template_size : int
    frames : sequence of (H, W, 3) uint8, optional
        The frames; or give ``render`` and ``length``.
    render : callable, optional
        ``render(t)`` -> frame ``t`` (0-based) as ``(H, W, 3)`` uint8, deterministic.
    length : int, optional
        Number of frames (required with ``render``).
    ids : (N,) int, optional
        Ground-truth ids (with ``points``).
    points : (T, N, 2) float, optional
        Ground-truth head centres in pixels, NaN where absent.
    init : Births, optional
        Explicit starting targets and births; default: from the ground truth.
    output : callable, optional
        ``output(frames) -> frames``, applied to the rendered stream (e.g.
        :func:`synth_data.video.camera_output`: the codec and JPEG steps of ``generate``).
    """

    def __init__(
        self,
        *,
        name: str,
        frame_rate: float,
        width: int,
        height: int,
        template_size: int,
        frames: Sequence[np.ndarray] | None = None,
        render: Callable[[int], np.ndarray] | None = None,
        length: int | None = None,
        ids: np.ndarray | None = None,
        points: np.ndarray | None = None,
        init: Births | None = None,
        output: Callable[[Iterable[np.ndarray]], Iterator[np.ndarray]] | None = None,
    ) -> None:
        owner = f"InMemorySequence {name!r}"
        require_number(owner, "frame_rate", frame_rate, lo=0, lo_open=True)
        for key, value in (("width", width), ("height", height)):
            require_number(owner, key, value, lo=1, integer=True)
        require_number(owner, "template_size", template_size, lo=2, integer=True)
        if (frames is None) == (render is None):
            raise ValueError(f"{owner}: give exactly one of frames and render")
        if frames is not None:
            if length is not None and length != len(frames):
                raise ValueError(f"{owner}: length {length} != {len(frames)} frames")
            length = len(frames)
            for t, f in enumerate(frames):  # what every tracker reads: BGR uint8 of this size
                shape, dtype = getattr(f, "shape", None), getattr(f, "dtype", None)
                if shape != (height, width, 3) or dtype != np.uint8:
                    raise ValueError(
                        f"{owner}: frame {t} must be ({height}, {width}, 3) uint8, got "
                        f"{dtype} {shape}"
                    )
        elif length is None:
            raise ValueError(f"{owner}: a render function needs the length")
        require_number(owner, "length", length, lo=0, integer=True)
        if (ids is None) != (points is None):
            raise ValueError(f"{owner}: give both ids and points, or neither")
        if ids is None:
            ids, points = _no_gt(int(length))
        ids = checked_ids(f"{owner}: ids", ids)  # 1.5 is not person 1, twice-listed is two
        points = np.asarray(points, dtype=np.float64)
        if points.shape != (length, len(ids), 2):
            raise ValueError(
                f"{owner}: points must have shape ({length}, {len(ids)}, 2), got {points.shape}"
            )
        if init is not None and not (isinstance(init, (tuple, list)) and len(init) == 2):
            raise ValueError(
                f"{owner}: init must be (ids, points) of the first frame, got {init!r:.60}"
            )
        self.name = str(name)
        self.frame_rate = float(frame_rate)
        self.width, self.height = int(width), int(height)
        self.template_size = int(template_size)
        self.length = int(length)
        self._frames = frames
        self._render = render
        self._ids, self._points = ids, points
        self._init = init
        self._output = output

    def __repr__(self) -> str:
        kind = "in memory" if self._frames is not None else "rendered on demand"
        return (
            f"InMemorySequence({self.name!r}, {self.length} frames {kind}, "
            f"{self.width}x{self.height}, {len(self._ids)} people)"
        )

    # -- constructors
    @classmethod
    def from_scene(cls, scene: Any, output: Callable | None = None) -> InMemorySequence:
        """Frames drawn on demand from a :class:`synth_data.scene.Scene` (then ``output``)."""
        ids, points = scene.gt_points()
        return cls(
            name=scene.name,
            frame_rate=scene.frame_rate,
            width=scene.width,
            height=scene.height,
            template_size=scene.template_size,
            render=scene.frame,
            length=scene.length,
            ids=ids,
            points=points,
            output=output,
        )

    @classmethod
    def from_spec(
        cls, spec: Any, frames: int | None = None, camera_output: bool = False
    ) -> InMemorySequence:
        """Simulate ``spec`` (truncated to ``frames`` like ``generate --frames``) and render
        it on demand, without touching disk.

        ``camera_output=False``: the rendered frames, which ``generate`` then passes through
        the video codec (``appearance.video_kbps > 0``) and JPEG. ``camera_output=True``:
        those two steps too, in memory (:func:`synth_data.video.camera_output`, the writer's
        code path), so the frames are exactly the ones a tracker reads from the generated
        folder. The ground truth equals
        ``read_sequence(...).gt_points()`` of the generated folder (to the 3 decimals of
        ``gt.txt``).
        """
        from functools import partial

        from synth_data.scene import Scene
        from synth_data.spec import SequenceSpec, spec_from_dict
        from synth_data.video import camera_output as camera

        if isinstance(spec, dict):  # a spec's table, as a spec file holds it
            spec = spec_from_dict(spec, "spec")
        if not isinstance(spec, SequenceSpec):
            raise ValueError(
                f"spec must be a SequenceSpec (synth_data.spec.load_spec) or its table, got "
                f"{type(spec).__name__}"
            )
        if frames is not None:
            require_number("InMemorySequence.from_spec", "frames", frames, lo=1, integer=True)
            spec = spec.truncated(int(frames))
        output = (
            partial(camera, fps=spec.fps, encoding=spec.appearance.encoding)
            if camera_output
            else None
        )
        return cls.from_scene(Scene.from_spec(spec), output=output)

    @classmethod
    def from_source(cls, source: SequenceSource, max_frames: int | None = None) -> InMemorySequence:
        """Read the first ``max_frames`` frames (all by default) of any source into memory."""
        n = source.length if max_frames is None else min(int(max_frames), source.length)
        frames = list(itertools.islice(source.frames(), n))
        ids, points = source.gt_points()
        return cls(
            name=source.name,
            frame_rate=source.frame_rate,
            width=source.width,
            height=source.height,
            template_size=source.template_size,
            frames=frames,
            ids=ids,
            points=points[: len(frames)],
        )

    def materialize(self) -> InMemorySequence:
        """The same sequence with every frame rendered into a list (e.g. to time tracking
        without rendering); the ``output`` step is applied once, here."""
        if self._frames is not None and self._output is None:
            return self
        return InMemorySequence(
            name=self.name,
            frame_rate=self.frame_rate,
            width=self.width,
            height=self.height,
            template_size=self.template_size,
            frames=list(self.frames()),
            ids=self._ids,
            points=self._points,
            init=self._init,
        )

    # -- the SequenceSource face
    def frames(self) -> Iterator[np.ndarray]:
        if self._output is not None:
            yield from self._output(self._raw_frames())
        else:
            yield from self._raw_frames()

    def _raw_frames(self) -> Iterator[np.ndarray]:
        if self._frames is not None:
            yield from self._frames
            return
        assert self._render is not None
        for t in range(self.length):
            yield self._render(t)

    def gt_points(self) -> tuple[np.ndarray, np.ndarray]:
        return self._ids, self._points

    def births(self) -> Births:
        if self._init is not None:
            return self._init
        if len(self._ids) == 0:
            raise ValueError(f"{self.name}: no ground truth to start the targets from")
        return births_from_ground_truth(self._ids, self._points, (self.width, self.height))


# ---------------------------------------------------------------------------- factories
def open_sequence(
    path: str | os.PathLike[str], init: str | os.PathLike[str] | None = None
) -> SequenceSource:
    """A MOTChallenge sequence folder or a video file, with optional points CSV ``init``.

    Raises ``ValueError`` naming ``path`` when it is neither.
    """
    from synth_data.mot import read_sequence

    p = Path(path)
    if p.is_dir():
        seq = read_sequence(p)
        seq.init = None if init is None else Path(init)
        return seq
    if p.is_file():
        return VideoSequence(p, init=init)
    raise ValueError(f"{p}: no such sequence folder or video file")


def synthetic_crowd(
    n: int,
    n_frames: int,
    seed: int = 0,
    template_px: int = 12,
    size: tuple[int, int] = (1280, 720),
    fps: float = 25.0,
    speed: float = 1.3,
    contrast: float = 1.0,
    noise_sigma: float = 3.0,
) -> InMemorySequence:
    """Render ``n`` people in lanes of opposite flows (counterflow bands of 4 m), in memory.

    People start on a jittered grid that fills the frame, walk along x at N(speed, 0.15) m/s
    (alternate 4 m bands walk the other way) with a slow sinusoidal weave, so that the
    neighbourhood-motion and grouping terms have coherent groups to find. ``contrast`` and
    ``noise_sigma`` are the renderer's appearance knobs (lower contrast, more noise = harder).
    Frames are rendered up front (a list), so tracking timings exclude rendering. Ground
    truth: ids ``1..n``, points ``(n_frames, n, 2)`` px, NaN outside the frame.
    """
    from crowdsim.appearance_model import AppearanceParams
    from crowdsim.camera import Camera
    from crowdsim.checks import require_number
    from crowdsim.render import SceneRenderer, default_px_per_m, prepare_agents
    from crowdsim.trajectories import Trajectories

    require_number("synthetic_crowd", "n", n, lo=1, hi=100_000, integer=True)
    require_number("synthetic_crowd", "n_frames", n_frames, lo=2, hi=100_000, integer=True)
    require_number("synthetic_crowd", "template_px", template_px, lo=2, hi=256, integer=True)
    n, n_frames = int(n), int(n_frames)
    rng = np.random.default_rng(seed)
    ppm = default_px_per_m(template_px)
    w_m, h_m = size[0] / ppm, size[1] / ppm
    cols = max(1, int(round(math.sqrt(n * w_m / h_m))))
    rows = int(math.ceil(n / cols))
    gx, gy = np.meshgrid((np.arange(cols) + 0.5) * w_m / cols, (np.arange(rows) + 0.5) * h_m / rows)
    start = np.stack([gx.ravel(), gy.ravel()], 1)[:n]
    cell = min(w_m / cols, h_m / rows)
    start += rng.uniform(-0.2, 0.2, start.shape) * cell
    direction = np.where((start[:, 1] // 4.0) % 2 == 0, 1.0, -1.0)
    v = direction * rng.normal(speed, 0.15, n)
    dt = 1.0 / fps
    t = np.arange(n_frames)[:, None] * dt
    phase = rng.uniform(0, 2 * math.pi, n)
    pos = np.empty((n_frames, n, 2))
    pos[..., 0] = start[:, 0] + v * t
    pos[..., 1] = start[:, 1] + 0.15 * np.sin(0.8 * t + phase)
    traj = Trajectories(pos, np.arange(1, n + 1), dt)
    cam = Camera(px_per_m=ppm, width=size[0], height=size[1], center=(w_m / 2, h_m / 2))
    params = AppearanceParams(template_px=template_px, contrast=contrast, noise_sigma=noise_sigma)
    tracks = prepare_agents(traj, cam, params, seed)
    renderer = SceneRenderer(cam, params, seed, fps)
    frames = [renderer.render_tracks(tracks, k).copy() for k in range(n_frames)]
    pts = tracks.pixels.copy()
    inside = (
        (pts[..., 0] >= 0)
        & (pts[..., 0] <= size[0] - 1)
        & (pts[..., 1] >= 0)
        & (pts[..., 1] <= size[1] - 1)
    )
    pts[~inside] = np.nan
    return InMemorySequence(
        name=f"synthetic-crowd-n{n}-s{seed}",
        frame_rate=fps,
        width=size[0],
        height=size[1],
        template_size=template_px,
        frames=frames,
        ids=traj.ids.copy(),
        points=pts,
    )


def load_crowd(seq_dir: str | os.PathLike[str], max_frames: int | None = None) -> InMemorySequence:
    """A MOT sequence folder (e.g. from ``crowdsim generate``) read into memory; it must have
    ground truth."""
    from synth_data.mot import read_sequence

    seq = read_sequence(seq_dir)
    if len(seq.gt_points()[0]) == 0:
        raise ValueError(f"{seq_dir}: the sequence has no ground truth")
    return InMemorySequence.from_source(seq, max_frames)
