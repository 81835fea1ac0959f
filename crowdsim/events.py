"""Scheduled events: what changes part-way through a sequence (issue 15's non-stationary scenes).

A sequence spec may list events (``[[events]]`` tables in TOML). Each has a ``kind``, a first
frame ``start`` (0-based, counted after the warm-up), a length ``frames`` (``0``: until the
end) and a ``magnitude`` whose meaning depends on the kind:

=========  ===========================================================  ============
kind       what happens from ``start`` for ``frames`` frames            magnitude
=========  ===========================================================  ============
lighting   the scene's light level is multiplied (a cloud, lights       factor
           switched off or on); people and ground alike                 0.1 .. 3
noise      sensor noise of this standard deviation (grey levels), if    sigma
           above the sequence's own (gain pushed up at dusk)            0 .. 60
shake      camera shake of this standard deviation (px) on top of the   px
           sequence's own (a truck passing, a gust on a mast); the      0 .. 200
           ground truth moves with the image
stop       this fraction of the people present stops where it stands   fraction
           (desired velocity held at zero), then walks on                0 .. 1
surge      every inflow's arrival rate is multiplied (a train arrives,  factor
           a gate opens): density rises; needs a scenario with inflow   1 .. 50
=========  ===========================================================  ============

Scene events (lighting, noise, shake) are drawn by the renderer and the camera; crowd events
(stop, surge) act on the simulation. Every draw is seeded: the same spec gives the same frames.

>>> ev = Event("lighting", start=10, frames=5, magnitude=0.5)
>>> [ev.active(t) for t in (9, 10, 14, 15)]
[False, True, True, False]
>>> Event("stop", start=0, magnitude=1.5)
Traceback (most recent call last):
...
ValueError: events[0].magnitude must be a finite number in [0, 1], got 1.5
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from crowdsim.checks import require_number

EVENT_KINDS: dict[str, tuple[float, float, str]] = {
    "lighting": (0.1, 3.0, "factor on the light level"),
    "noise": (0.0, 60.0, "sensor noise sigma, grey levels"),
    "shake": (0.0, 200.0, "camera shake sigma, px"),
    "stop": (0.0, 1.0, "fraction of the people present who stop"),
    "surge": (1.0, 50.0, "factor on every inflow's arrival rate"),
}
"""Event kind -> (lowest magnitude, highest magnitude, what the magnitude is)."""
SCENE_EVENTS: tuple[str, ...] = ("lighting", "noise", "shake")
"""Kinds drawn by the renderer and the camera."""
CROWD_EVENTS: tuple[str, ...] = ("stop", "surge")
"""Kinds that act on the simulation."""
EVENT_FIELDS: tuple[str, ...] = ("kind", "start", "frames", "magnitude")


@dataclass(frozen=True)
class Event:
    """One scheduled change (see the module docstring for the kinds).

    Attributes
    ----------
    kind : str
        One of :data:`EVENT_KINDS`.
    start : int
        First frame (0-based, after the warm-up) the event acts on.
    frames : int
        How many frames it lasts; ``0`` means until the end of the sequence.
    magnitude : float
        Its strength, in the kind's unit and range (:data:`EVENT_KINDS`).
    index : int
        Position in the spec's list (for error messages; not compared).
    ordinal : int
        Position among the spec's events of the same kind (a shake burst's seed; not
        compared): it stays when ``--frames`` drops later events.
    """

    kind: str
    start: int
    frames: int = 0
    magnitude: float = 1.0
    index: int = field(default=0, compare=False, repr=False)
    ordinal: int = field(default=0, compare=False, repr=False)

    def __post_init__(self) -> None:
        own = f"events[{self.index}]"
        if not isinstance(self.kind, str) or self.kind not in EVENT_KINDS:
            raise ValueError(
                f"{own}.kind must be one of {', '.join(EVENT_KINDS)}, got {self.kind!r}"
            )
        require_number(own, "start", self.start, lo=0, integer=True)
        require_number(own, "frames", self.frames, lo=0, integer=True)
        lo, hi, _ = EVENT_KINDS[self.kind]
        require_number(own, "magnitude", self.magnitude, lo=lo, hi=hi)
        object.__setattr__(self, "start", int(self.start))
        object.__setattr__(self, "frames", int(self.frames))
        object.__setattr__(self, "magnitude", float(self.magnitude))

    @property
    def stop(self) -> float:
        """First frame after the event (``inf`` when it lasts to the end)."""
        return self.start + self.frames if self.frames else float("inf")

    def active(self, t: int) -> bool:
        """Whether the event acts on frame ``t``."""
        return self.start <= t < self.stop

    def mask(self, n_frames: int) -> np.ndarray:
        """``(n_frames,)`` bool: the frames it acts on."""
        t = np.arange(n_frames)
        return (t >= self.start) & (t < self.stop)

    def to_dict(self) -> dict[str, Any]:
        return {
            "kind": self.kind,
            "start": self.start,
            "frames": self.frames,
            "magnitude": self.magnitude,
        }


def parse_events(value: Any, where: str = "spec", n_frames: int | None = None) -> tuple[Event, ...]:
    """Events from a list of tables (a spec's ``events``); every problem is a ``ValueError``
    naming ``where``, the entry and the field. With ``n_frames``, an event must start inside
    the sequence."""
    if value is None:
        return ()
    if isinstance(value, Mapping) or not isinstance(value, Sequence) or isinstance(value, str):
        raise ValueError(f"{where}: events must be a list of tables, got {value!r}")
    out = []
    for i, item in enumerate(value):
        if isinstance(item, Event):
            item = item.to_dict()
        if not isinstance(item, Mapping):
            raise ValueError(f"{where}: events[{i}] must be a table, got {item!r}")
        unknown = sorted(str(k) for k in set(item) - set(EVENT_FIELDS))
        if unknown:
            raise ValueError(
                f"{where}: unknown field(s) events[{i}].{', '.join(unknown)}; "
                f"valid: {', '.join(EVENT_FIELDS)}"
            )
        for key in ("kind", "start"):
            if key not in item:
                raise ValueError(f"{where}: missing required field 'events[{i}].{key}'")
        try:
            ev = Event(
                kind=item["kind"],
                start=item["start"],
                frames=item.get("frames", 0),
                magnitude=item.get("magnitude", 1.0),
                index=i,
                ordinal=sum(1 for e in out if e.kind == item["kind"]),
            )
        except ValueError as exc:
            raise ValueError(f"{where}: {exc}") from None
        if n_frames is not None and ev.start >= n_frames:
            raise ValueError(
                f"{where}: events[{i}].start must be below the sequence's {n_frames} frames, "
                f"got {ev.start}"
            )
        out.append(ev)
    return tuple(out)


def of_kind(events: Sequence[Event], kinds: Sequence[str]) -> tuple[Event, ...]:
    """The events whose kind is in ``kinds``."""
    return tuple(e for e in events if e.kind in kinds)


def light_factor(events: Sequence[Event], t: int) -> float:
    """Product of the lighting factors acting on frame ``t`` (1 without any)."""
    f = 1.0
    for e in events:
        if e.kind == "lighting" and e.active(t):
            f *= e.magnitude
    return f


def noise_sigma(events: Sequence[Event], t: int, base: float) -> float:
    """Sensor noise sigma of frame ``t``: the largest of ``base`` and the active bursts."""
    s = float(base)
    for e in events:
        if e.kind == "noise" and e.active(t):
            s = max(s, e.magnitude)
    return s
