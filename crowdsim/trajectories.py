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
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from crowdsim.atomic import atomic_path

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
        if len(np.unique(self.ids)) != n:
            raise ValueError("ids must be unique")
        if not (np.isfinite(self.dt) and self.dt > 0):
            raise ValueError(f"dt must be a positive number of seconds, got {self.dt!r}")
        for name, (dtype, fill) in ATTRIBUTE_DEFAULTS.items():
            value = self.attributes.get(name)
            if value is None:
                self.attributes[name] = np.full(n, fill, dtype=dtype)
            else:
                value = np.asarray(value, dtype=dtype)
                if value.shape != (n,):
                    raise ValueError(f"attribute {name!r} must have shape ({n},), "
                                     f"got {value.shape}")
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

    def velocities(self) -> np.ndarray:
        """``(T, N, 2)`` m/s by backward differences; NaN at entry rows and where absent."""
        vel = np.full_like(self.positions, np.nan)
        vel[1:] = (self.positions[1:] - self.positions[:-1]) / self.dt
        return vel

    def extent(self) -> tuple[float, float, float, float]:
        """``(xmin, ymin, xmax, ymax)`` in metres over all present positions."""
        if not self.present.any():
            raise ValueError("trajectories contain no present position")
        xy = self.positions[self.present]
        return (float(xy[:, 0].min()), float(xy[:, 1].min()), float(xy[:, 0].max()),
                float(xy[:, 1].max()))

    # ------------------------------------------------------------------ npz
    def save(self, path: str | os.PathLike[str]) -> Path:
        """Write an ``.npz`` atomically (temporary file in the same folder, then rename)."""
        path = Path(path)
        if path.suffix != ".npz":
            raise ValueError(f"trajectory file must end in .npz, got {str(path)!r}")
        arrays = {f"attr_{k}": v for k, v in self.attributes.items()}
        with atomic_path(path) as tmp:
            np.savez_compressed(tmp, positions=self.positions, ids=self.ids,
                                dt=np.float64(self.dt), meta=np.str_(json.dumps(self.meta)),
                                **arrays)
        return path

    @classmethod
    def load(cls, path: str | os.PathLike[str]) -> Trajectories:
        """Read an ``.npz`` written by :meth:`save`; errors name the file and the missing key."""
        path = Path(path)
        try:
            data = np.load(path, allow_pickle=False)
        except FileNotFoundError:
            raise ValueError(f"{path}: no such trajectory file") from None
        except (OSError, ValueError) as exc:
            raise ValueError(f"{path}: not a readable .npz file ({exc})") from None
        with data:
            for key in ("positions", "ids", "dt"):
                if key not in data.files:
                    raise ValueError(f"{path}: missing array {key!r}")
            attrs = {k[5:]: data[k] for k in data.files if k.startswith("attr_")}
            meta = json.loads(str(data["meta"])) if "meta" in data.files else {}
            return cls(positions=data["positions"], ids=data["ids"], dt=float(data["dt"]),
                       attributes=attrs, meta=meta)

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
    def from_csv(cls, path: str | os.PathLike[str], fps: float) -> Trajectories:
        """Read ``frame,id,x,y`` rows (metres; a header line is optional).

        Frames may start anywhere; they are shifted so the first frame is row 0. Errors name
        the file, the line and the offending value.
        """
        path = Path(path)
        if not (np.isfinite(fps) and fps > 0):
            raise ValueError(f"fps must be positive, got {fps!r}")
        if not path.is_file():
            raise ValueError(f"{path}: no such trajectory file")
        rows: list[tuple[int, int, float, float]] = []
        with open(path) as fh:
            for lineno, line in enumerate(fh, 1):
                line = line.strip()
                if not line or line.startswith("#"):
                    continue
                parts = [p.strip() for p in line.replace(";", ",").split(",")]
                if lineno == 1 and not _is_number(parts[0]):
                    continue  # header
                if len(parts) < 4:
                    raise ValueError(f"{path}:{lineno}: expected 4 columns frame,id,x,y, "
                                     f"got {len(parts)}: {line!r}")
                try:
                    frame, ident = int(float(parts[0])), int(float(parts[1]))
                    x, y = float(parts[2]), float(parts[3])
                except ValueError:
                    raise ValueError(f"{path}:{lineno}: non-numeric value in {line!r}") from None
                if not (np.isfinite(x) and np.isfinite(y)):
                    raise ValueError(f"{path}:{lineno}: position must be finite, got {line!r}")
                rows.append((frame, ident, x, y))
        if not rows:
            raise ValueError(f"{path}: no trajectory rows")
        arr = np.array(rows, dtype=np.float64)
        frames = arr[:, 0].astype(np.int64)
        frames -= frames.min()
        ids, col = np.unique(arr[:, 1].astype(np.int64), return_inverse=True)
        positions = np.full((frames.max() + 1, len(ids), 2), np.nan)
        positions[frames, col] = arr[:, 2:4]
        return cls(positions=positions, ids=ids, dt=1.0 / fps, meta={"source": str(path)})


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

    def finish(self, n_total: int, dt: float, attributes: dict[str, np.ndarray],
               meta: dict[str, Any]) -> Trajectories:
        """Build the dense ``(T, n_total, 2)`` trajectories."""
        out = np.full((len(self._ids), n_total, 2), np.nan)
        for t, (ids, pos) in enumerate(zip(self._ids, self._pos, strict=False)):
            out[t, ids] = pos
        return Trajectories(positions=out, ids=np.arange(n_total, dtype=np.int64), dt=dt,
                            attributes={k: v[:n_total] for k, v in attributes.items()}, meta=meta)
