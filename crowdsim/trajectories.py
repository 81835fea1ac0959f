"""Trajectories: the recorded output of a simulation (SPEC §2).

A :class:`Trajectories` holds

* ``positions``: ``(T, N, 2)`` float64, metres, NaN where agent ``n`` is absent at step ``t``;
* ``ids``: ``(N,)`` int64, stable agent ids (never reused);
* ``attributes``: per-agent ``(N,)`` arrays: ``group`` (int, -1 = none), ``prominent`` (bool),
  ``anomaly`` (int, see :data:`ANOMALY_KINDS`), ``radius`` (m), ``desired_speed`` (m/s);
* ``dt``: seconds between consecutive rows.

It saves to and loads from ``.npz`` (atomically: temporary file, then rename) and reads and
writes the ``frame,id,x,y`` CSV shape that public pedestrian data sets use.
"""

from __future__ import annotations

import json
import math
import os
import re
import zipfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from crowdsim.atomic import atomic_path
from crowdsim.checks import require_memory

CSV_COLUMNS: tuple[str, ...] = ("frame", "id", "x", "y")
"""Columns of a trajectory CSV file, in this order (metres for x and y)."""
MAX_COORD_M: float = 1e5
"""Largest ``|x|`` or ``|y|`` (metres) a trajectory may hold: 100 km. Beyond it the pixel
coordinates of any useful camera overflow, and such a value is a unit or parsing mistake."""
MAX_TRAJECTORY_BYTES: int = 4 * 2**30
"""Largest dense ``(T, N, 2)`` float64 position array a file may expand to (4 GiB)."""

ANOMALY_KINDS: tuple[str, ...] = ("none", "against", "stop", "cross", "leave")
"""Anomaly codes stored in ``attributes["anomaly"]``: index into this tuple."""

ATTRIBUTE_DEFAULTS: dict[str, tuple[Any, Any]] = {
    "group": (np.int64, -1),
    "prominent": (np.bool_, False),
    "anomaly": (np.int8, 0),
    "radius": (np.float64, 0.22),
    "desired_speed": (np.float64, 1.34),
}
"""Per-agent attribute name -> (dtype, fill value) used when a source omits one."""


@dataclass
class Trajectories:
    """Positions of every agent that ever existed, one row per recorded step.

    Attributes
    ----------
    positions : (T, N, 2) float64
        Metres; NaN where the agent is absent (not yet entered, or already left).
    ids : (N,) int64
        Stable integer agent ids, column ``n`` belongs to ``ids[n]``.
    dt : float
        Seconds between consecutive rows of ``positions``.
    attributes : dict[str, (N,) ndarray]
        Per-agent attributes, see :data:`ATTRIBUTE_DEFAULTS`.
    meta : dict
        JSON-serialisable description (scenario, parameters, seed, versions).
    """

    positions: np.ndarray
    ids: np.ndarray
    dt: float
    attributes: dict[str, np.ndarray] = field(default_factory=dict)
    meta: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.positions = np.asarray(self.positions, dtype=np.float64)
        self.ids = np.asarray(self.ids, dtype=np.int64)
        if self.positions.ndim != 3 or self.positions.shape[2] != 2:
            raise ValueError(f"positions must have shape (T, N, 2), got {self.positions.shape}")
        n = self.positions.shape[1]
        if self.ids.shape != (n,):
            raise ValueError(f"ids must have shape ({n},), got {self.ids.shape}")
        uniq, counts = np.unique(self.ids, return_counts=True)
        if len(uniq) != n:
            raise ValueError(
                f"ids must be unique, id {uniq[counts > 1][0]} appears "
                f"{counts[counts > 1][0]} times"
            )
        if not (np.isfinite(self.dt) and self.dt > 0):
            raise ValueError(f"dt must be a positive number of seconds, got {self.dt!r}")
        for name, (dtype, fill) in ATTRIBUTE_DEFAULTS.items():
            value = self.attributes.get(name)
            if value is None:
                self.attributes[name] = np.full(n, fill, dtype=dtype)
            else:
                value = np.asarray(value, dtype=dtype)
                if value.shape != (n,):
                    raise ValueError(
                        f"attribute {name!r} must have shape ({n},), got {value.shape}"
                    )
                self.attributes[name] = value

    # ------------------------------------------------------------------ shape helpers
    @property
    def n_steps(self) -> int:
        """Number of recorded rows ``T``."""
        return self.positions.shape[0]

    @property
    def n_agents(self) -> int:
        """Number of distinct agents ``N`` that ever existed."""
        return self.positions.shape[1]

    @property
    def fps(self) -> float:
        """Rows per second (``1 / dt``)."""
        return 1.0 / self.dt

    @property
    def present(self) -> np.ndarray:
        """``(T, N)`` bool, True where the agent is present."""
        return ~np.isnan(self.positions[..., 0])

    @property
    def period(self) -> float:
        """Length of a periodic x axis (m) from ``meta`` (0 = none)."""
        value = self.meta.get("period", 0.0) or 0.0
        try:
            period = float(value)
        except (TypeError, ValueError):
            period = math.nan
        if not (math.isfinite(period) and period >= 0):
            raise ValueError(f"trajectories meta.period must be a length >= 0 m, got {value!r}")
        return period

    def steps(self) -> np.ndarray:
        """``(T - 1, N, 2)`` metres moved from each row to the next (NaN where absent in
        either). On a periodic x axis a step across the seam counts as the short way round."""
        d = self.positions[1:] - self.positions[:-1]
        if self.period > 0:
            d[..., 0] -= self._seam_shift(d[..., 0])
        return d

    def _seam_shift(self, dx: np.ndarray) -> np.ndarray:
        """The whole periods a step ``dx`` along the periodic x axis drops to go the short
        way round (:meth:`steps`, :meth:`unwrapped`)."""
        return self.period * np.round(dx / self.period)

    def velocities(self) -> np.ndarray:
        """``(T, N, 2)`` m/s by backward differences (:meth:`steps`); NaN at entry rows and
        where absent."""
        vel = np.full_like(self.positions, np.nan)
        vel[1:] = self.steps() / self.dt
        return vel

    def unwrapped(self) -> np.ndarray:
        """``(T, N, 2)`` positions with a periodic x axis made continuous along each path:
        a step across the seam goes on past it (:meth:`steps`) instead of jumping back by a
        period, so differences over several rows (a heading, the distance walked) stay
        true. Across rows where a path is absent, its next present row goes on from its last
        present one. The positions themselves without a period."""
        if self.period <= 0 or self.n_steps < 2:
            return self.positions
        x = self.positions[..., 0]
        # each row's x, or the path's last present x before it: a gap's two ends are one step
        rows = np.where(np.isfinite(x), np.arange(self.n_steps)[:, None], 0)
        x = x[np.maximum.accumulate(rows, axis=0), np.arange(self.n_agents)]
        d = np.diff(x, axis=0)
        with np.errstate(invalid="ignore"):  # the short step less the step, as steps()
            jump = np.nan_to_num((d - self._seam_shift(d)) - d)
        out = self.positions.copy()
        out[1:, :, 0] += np.cumsum(jump, axis=0)
        return out

    def extent(self) -> tuple[float, float, float, float]:
        """``(xmin, ymin, xmax, ymax)`` in metres over all present positions."""
        if not self.present.any():
            raise ValueError("trajectories contain no present position")
        xy = self.positions[self.present]
        return (
            float(xy[:, 0].min()),
            float(xy[:, 1].min()),
            float(xy[:, 0].max()),
            float(xy[:, 1].max()),
        )

    # ------------------------------------------------------------------ npz
    def save(self, path: str | os.PathLike[str]) -> Path:
        """Write an ``.npz`` atomically (temporary file in the same folder, then rename)."""
        path = Path(path)
        if path.suffix != ".npz":
            raise ValueError(f"trajectory file must end in .npz, got {str(path)!r}")
        arrays = {f"attr_{k}": v for k, v in self.attributes.items()}
        with atomic_path(path) as tmp:
            np.savez_compressed(
                tmp,
                positions=self.positions,
                ids=self.ids,
                dt=np.float64(self.dt),
                meta=np.str_(json.dumps(self.meta)),
                **arrays,
            )
        return path

    @classmethod
    def load(cls, path: str | os.PathLike[str]) -> Trajectories:
        """Read an ``.npz`` written by :meth:`save`.

        Errors name the file and what is wrong with it: not a zip archive, a missing array,
        positions of the wrong shape, non-finite or out-of-range (:data:`MAX_COORD_M`)
        coordinates, duplicate ids, a bad ``dt``.
        """
        path = Path(path)
        if not path.exists():
            raise ValueError(f"{path}: no such trajectory file")
        if path.is_dir():
            raise ValueError(f"{path}: is a folder, not a trajectory .npz file")
        what = f"{path}: not a crowdsim trajectories .npz"
        with open(path, "rb") as fh:
            magic = fh.read(4)
        if magic != b"PK\x03\x04" and magic != b"PK\x05\x06":
            raise ValueError(
                f"{what} (not a zip archive; write one with crowdsim simulate --out FILE.npz)"
            )
        try:
            data = np.load(path, allow_pickle=False)
        except (OSError, ValueError, EOFError, zipfile.BadZipFile) as exc:
            raise ValueError(f"{what} ({_first_line(exc)})") from None
        if not isinstance(data, np.lib.npyio.NpzFile):  # pragma: no cover - np.load sniffing
            raise ValueError(f"{what} (a single array, not an archive)")
        with data:
            missing = [k for k in ("positions", "ids", "dt") if k not in data.files]
            if missing:
                raise ValueError(
                    f"{what} (missing array {missing[0]!r}; it has "
                    f"{', '.join(data.files) or 'no arrays'})"
                )
            try:
                arrays = {k: data[k] for k in data.files}
            except (OSError, ValueError, EOFError, zipfile.BadZipFile) as exc:
                raise ValueError(f"{what} ({_first_line(exc)})") from None
        try:
            meta = json.loads(str(arrays["meta"])) if "meta" in arrays else {}
        except json.JSONDecodeError:
            raise ValueError(f"{what} (array 'meta' is not JSON)") from None
        positions, ids, dt = arrays["positions"], arrays["ids"], arrays["dt"]
        if positions.dtype.kind not in "fiu":
            raise ValueError(f"{path}: positions must be numbers, got dtype {positions.dtype}")
        if ids.dtype.kind not in "iu":
            raise ValueError(f"{path}: ids must be integers, got dtype {ids.dtype}")
        if dt.shape != () or dt.dtype.kind not in "fiu":
            raise ValueError(f"{path}: dt must be one number of seconds, got {dt!r}")
        if positions.ndim != 3 or positions.shape[2] != 2:
            raise ValueError(f"{path}: positions must have shape (T, N, 2), got {positions.shape}")
        check_positions(positions, str(path))
        attrs = {k[5:]: v for k, v in arrays.items() if k.startswith("attr_")}
        try:
            return cls(positions=positions, ids=ids, dt=float(dt), attributes=attrs, meta=meta)
        except ValueError as exc:
            raise ValueError(f"{path}: {exc}") from None

    # ------------------------------------------------------------------ csv
    def to_csv(self, path: str | os.PathLike[str]) -> Path:
        """Write ``frame,id,x,y`` rows (0-based frames, metres) atomically."""
        path = Path(path)
        t, n = np.nonzero(self.present)
        rows = np.column_stack([t, self.ids[n], self.positions[t, n, 0], self.positions[t, n, 1]])
        with atomic_path(path) as tmp, open(tmp, "w") as fh:
            fh.write("frame,id,x,y\n")
            np.savetxt(fh, rows, fmt=["%d", "%d", "%.6f", "%.6f"], delimiter=",")
        return path

    @classmethod
    def from_csv(
        cls,
        path: str | os.PathLike[str],
        fps: float,
        frame_step: int | None = None,
        period: float = 0.0,
    ) -> Trajectories:
        """Read ``frame,id,x,y`` rows (metres; a header line is optional).

        Columns are separated by commas, semicolons, tabs or spaces (public data sets use
        each); a UTF-8 byte-order mark and quoted header names are read. Frames may start
        anywhere; they are shifted so the first frame is row 0. Frames and ids must be whole
        numbers within int64 (``3`` or ``3.0``, never ``2.5``), coordinates finite with
        ``|x|, |y| <=`` :data:`MAX_COORD_M`, exactly four columns per row and one row per
        ``(frame, id)``. The dense ``(T, N, 2)`` array must fit in
        :data:`MAX_TRAJECTORY_BYTES`. Errors name the file, the line and the offending value.

        ``frame_step``: annotations every ``k``-th frame (ETH/UCY number their frames 0, 10,
        20, ...) become consecutive rows when ``k`` is given (every frame, less the first,
        must be a multiple of it away). Without it, frames that all step by more than one are
        refused, naming the step: rendered as they are, every person would show in one frame
        of ``k`` and vanish in the others. ``meta`` records ``first_frame`` and
        ``frame_step``, so each row maps back to the file's frame number.

        ``period``: the length (m) of a periodic x axis, as :meth:`to_csv` of a periodic
        world's run leaves it out (a CSV has no place for it); 0 for none. Speeds, headings
        and gaits then take a step across the seam the short way round (:meth:`steps`).
        """
        path = Path(path)
        if not (np.isfinite(fps) and fps > 0):
            raise ValueError(f"fps must be positive, got {fps!r}")
        if isinstance(period, bool) or not (
            isinstance(period, (int, float, np.number)) and 0 <= period <= MAX_COORD_M
        ):
            raise ValueError(f"period must be a length in [0, {MAX_COORD_M:g}] m, got {period!r}")
        if not path.exists():
            raise ValueError(f"{path}: no such trajectory file")
        if path.is_dir():
            raise ValueError(f"{path}: is a folder, not a trajectory CSV file")
        frames_l: list[int] = []
        ids_l: list[int] = []
        xy_l: list[tuple[float, float]] = []
        lines_l: list[int] = []
        try:
            fh = open(path, encoding="utf-8-sig")  # a spreadsheet's byte-order mark is fine
            with fh:
                for lineno, line in enumerate(fh, 1):
                    line = line.strip()
                    if not line or line.startswith("#"):
                        continue
                    parts = [p.strip().strip("\"'") for p in _CSV_SEPARATORS.split(line)]
                    if not frames_l and not _is_number(parts[0]):
                        if [p.lower() for p in parts] != list(CSV_COLUMNS):
                            raise ValueError(
                                f"{path}:{lineno}: the header must be "
                                f"{','.join(CSV_COLUMNS)}, got {line!r}"
                            )
                        continue
                    if len(parts) != len(CSV_COLUMNS):
                        raise ValueError(
                            f"{path}:{lineno}: expected 4 columns frame,id,x,y, "
                            f"got {len(parts)}: {line!r}"
                        )
                    where = f"{path}:{lineno}"
                    frames_l.append(_parse_int(parts[0], "frame", where))
                    ids_l.append(_parse_int(parts[1], "id", where))
                    x, y = (_parse_coord(v, k, where) for v, k in zip(parts[2:], "xy", strict=True))
                    xy_l.append((x, y))
                    lines_l.append(lineno)
        except UnicodeDecodeError:
            raise ValueError(f"{path}: not a text CSV file (undecodable bytes)") from None
        if not frames_l:
            raise ValueError(f"{path}: no trajectory rows")
        frames = np.array(frames_l, dtype=np.int64)
        raw_ids = np.array(ids_l, dtype=np.int64)
        t0, t1 = int(frames.min()), int(frames.max())
        ids, col = np.unique(raw_ids, return_inverse=True)
        n_rows = t1 - t0 + 1  # Python int: no overflow
        require_memory(
            f"{path}: frames {t0}..{t1} x {len(ids)} ids (a ({n_rows}, {len(ids)}, 2) "
            "float64 position array)",
            16.0 * n_rows * len(ids),
            MAX_TRAJECTORY_BYTES,
        )
        frames -= t0
        step = int(np.gcd.reduce(frames)) if frames.any() else 1
        if frame_step is None and step > 1:
            raise ValueError(
                f"{path}: every frame number steps by {step} (frames {t0}, {t0 + step}, "
                f"...): the people would show in one rendered frame of {step}; give "
                f"--frame-step {step} to take the annotated frames as consecutive ones, or "
                "--frame-step 1 to keep the gaps"
            )
        if frame_step is not None:
            if not (isinstance(frame_step, (int, np.integer)) and frame_step >= 1):
                raise ValueError(f"frame_step must be a whole number >= 1, got {frame_step!r}")
            off = np.flatnonzero(frames % frame_step)
            if len(off):
                i = int(off[0])
                raise ValueError(
                    f"{path}:{lines_l[i]}: frame {frames_l[i]} is not a multiple of "
                    f"--frame-step {frame_step} away from the first frame {t0}"
                )
            frames //= frame_step
            n_rows = int(frames.max()) + 1
        key = frames * len(ids) + col
        order = np.argsort(key, kind="stable")
        dup = np.nonzero(np.diff(key[order]) == 0)[0]
        if len(dup):
            a, b = order[dup[0]], order[dup[0] + 1]
            raise ValueError(
                f"{path}:{lines_l[b]}: frame {frames_l[b]}, id {ids_l[b]} appears "
                f"twice (also on line {lines_l[a]})"
            )
        xy = np.array(xy_l, dtype=np.float64)
        if period > 0:  # a periodic world's x lies on [0, period) (a CSV's 6 decimals may
            # round it up to the period): past it, another axis was given
            off = np.flatnonzero((xy[:, 0] < 0) | (xy[:, 0] > period))
            if len(off):
                i = int(off[0])
                raise ValueError(
                    f"{path}:{lines_l[i]}: x = {xy[i, 0]:g} m lies outside the periodic axis "
                    f"[0, {period:g}] m"
                )
        positions = np.full((n_rows, len(ids), 2), np.nan)
        positions[frames, col] = xy
        meta = {"source": str(path), "first_frame": t0, "frame_step": int(frame_step or 1)}
        if period > 0:
            meta["period"] = float(period)
        return cls(positions=positions, ids=ids, dt=1.0 / fps, meta=meta)


_CSV_SEPARATORS = re.compile(r"\s*[,;\t]\s*|\s+")
"""Column separators of a trajectory CSV: a comma, semicolon or tab (with spaces around),
or spaces alone."""


def check_positions(positions: np.ndarray, where: str) -> None:
    """Raise ``ValueError`` naming the first coordinate that is infinite or beyond
    :data:`MAX_COORD_M` metres (NaN marks an absent agent and is allowed).

    Parameters
    ----------
    positions : (T, N, 2) float
        Metres.
    where : str
        Prefix of the message (the file).
    """
    pos = np.asarray(positions, dtype=np.float64)
    with np.errstate(invalid="ignore"):
        bad = np.isinf(pos) | (np.abs(pos) > MAX_COORD_M)
    if bad.any():
        t, n, k = (int(v[0]) for v in np.nonzero(bad))
        raise ValueError(
            f"{where}: {'xy'[k]} = {pos[t, n, k]:g} m at row {t}, column {n} is "
            f"outside [-{MAX_COORD_M:g}, {MAX_COORD_M:g}] m"
        )


def _first_line(exc: BaseException) -> str:
    return (str(exc).strip().splitlines() or [type(exc).__name__])[0]


def _parse_int(text: str, name: str, where: str) -> int:
    """A whole number in the int64 range: ``"3"``, ``"+3"``, ``"3.0"``, ``"3e2"``."""
    try:
        value = int(text)
    except ValueError:
        try:
            f = float(text)
        except ValueError:
            raise ValueError(f"{where}: {name} {text!r} is not a number") from None
        if not np.isfinite(f):
            raise ValueError(f"{where}: {name} {text} is not finite") from None
        if not f.is_integer():
            raise ValueError(f"{where}: {name} {text} is not an integer") from None
        if not -(2.0**63) <= f < 2.0**63:
            raise ValueError(f"{where}: {name} {text} is outside the int64 range") from None
        if abs(f) > 2**53:  # beyond exact float integers: ask for the digits
            raise ValueError(
                f"{where}: {name} {text} is too large to be read exactly; write "
                "it as a whole number within int64"
            ) from None
        value = int(f)
    if not -(2**63) <= value < 2**63:
        raise ValueError(f"{where}: {name} {text} is outside the int64 range")
    return value


def _parse_coord(text: str, name: str, where: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise ValueError(f"{where}: {name} {text!r} is not a number") from None
    if not np.isfinite(value):
        raise ValueError(f"{where}: {name} {text} is not finite")
    if abs(value) > MAX_COORD_M:
        raise ValueError(
            f"{where}: {name} {text} m is outside [-{MAX_COORD_M:g}, {MAX_COORD_M:g}] m"
        )
    return value


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


class TrajectoryRecorder:
    """Collects the active agents' positions after each recorded step.

    Agent ids are dense and assigned in order of entry (0, 1, 2, ...), so the column of an
    agent in :attr:`Trajectories.positions` is its id. Memory grows with the number of
    *present* agents per row, not with ``T x N``, until :meth:`finish` builds the dense array.
    """

    def __init__(self) -> None:
        self._ids: list[np.ndarray] = []
        self._pos: list[np.ndarray] = []

    def record(self, ids: np.ndarray, positions: np.ndarray) -> None:
        """Append one row: ``ids (n,)`` and ``positions (n, 2)`` of the present agents."""
        self._ids.append(np.array(ids, dtype=np.int64))
        self._pos.append(np.array(positions, dtype=np.float64))

    def __len__(self) -> int:
        return len(self._ids)

    def finish(
        self, n_total: int, dt: float, attributes: dict[str, np.ndarray], meta: dict[str, Any]
    ) -> Trajectories:
        """Build the dense ``(T, n_total, 2)`` trajectories."""
        out = np.full((len(self._ids), n_total, 2), np.nan)
        for t, (ids, pos) in enumerate(zip(self._ids, self._pos, strict=False)):
            out[t, ids] = pos
        return Trajectories(
            positions=out,
            ids=np.arange(n_total, dtype=np.int64),
            dt=dt,
            attributes={k: v[:n_total] for k, v in attributes.items()},
            meta=meta,
        )
