"""Every tracker by name: one table, read by the CLI, the demo, the benchmarks and the tests.

A tracker is registered as a lazily imported ``"module:Class"`` with its parameter dataclass
and the parameter overrides that make the named variant (``bqp-ncc`` is the BQP tracker with
NCC appearance). Adding a tracker to this package is one line in :data:`TRACKERS`; its tests
then ask for its accuracy floor on the planted crowd (``tests/tracker/accuracy_floor.json``: a
few points under what ``test_plant_and_recover_accuracy_floor`` measures), and a row in
:data:`envs.param_space.TUNABLES` makes it tunable. ``crowdsim compare --trackers NAME`` gives it
a row of its own.

A tracker of your own, outside this package, is registered in one of two ways:

* **An entry point** (what the CLI and its worker processes see). Your package declares, in its
  ``pyproject.toml``::

      [project.entry-points."crowdsim.trackers"]
      mine = "my_package.crowd:ENTRY"

  where ``ENTRY = tracker.registry.entry("mine", "my_package.crowd:MyTracker",
  "my_package.crowd:MyParams", "a one-line summary")``. Once the package is installed,
  ``crowdsim track --tracker mine``, ``crowdsim compare --trackers mine`` and
  :func:`make_tracker` find it in every process of an environment it is installed in
  (local pool workers; Ray tasks where the cluster's environment has it). Its module is
  imported only when the tracker is asked for (``--help`` lists it by name), so a broken
  plug-in fails naming itself, never another command.
* **:func:`register`**, for this Python process alone (a notebook, a script that calls
  :func:`tracker.runner.run_tracker` or builds the tuning environment in process). Spawned
  worker processes do not see it: give jobs with several workers an entry point.

Either way, :func:`tracker.testing.check_tracker_contract` checks the tracker against the
contract the runner, the environments and the metrics rely on.

>>> sorted(names())[:3]
['bqp', 'bqp-dense', 'bqp-ncc']
>>> get("kalman")  # doctest: +ELLIPSIS
Traceback (most recent call last):
...
ValueError: unknown tracker 'kalman'; valid trackers: bqp, bqp-ncc, bqp-dense, ncc...
>>> type(make_tracker("bqp-ncc").params).__name__, make_tracker("bqp-ncc").params.appearance
('BQPParams', 'ncc')
"""

from __future__ import annotations

import functools
import importlib
import re
import threading
from collections.abc import Mapping
from dataclasses import dataclass, field, fields, is_dataclass, replace
from types import MappingProxyType
from typing import Any

from tracker.base import Tracker


def _load(target: str) -> Any:
    module, _, attr = target.partition(":")
    return getattr(importlib.import_module(module), attr)


@dataclass(frozen=True)
class TrackerEntry:
    """One registered tracker.

    Attributes
    ----------
    name : str
        Registry name (``crowdsim track --tracker NAME``).
    target : str
        ``"module:Class"`` of the :class:`tracker.base.Tracker` subclass, imported on use.
    params : str
        ``"module:Class"`` of its frozen parameter dataclass.
    overrides : mapping
        Parameter values that make this variant (applied over the dataclass defaults).
    summary : str
        One line for ``--help`` and tables.
    """

    name: str
    target: str
    params: str
    overrides: Mapping[str, Any] = field(default_factory=dict)
    summary: str = ""

    def tracker_class(self) -> type[Tracker]:
        return _load(self.target)

    def params_class(self) -> type:
        return _load(self.params)

    def field_names(self) -> frozenset[str]:
        """The fields of its parameter class (what ``--set`` and overrides may name)."""
        return frozenset(f.name for f in fields(self.params_class()))

    def make_params(self, **overrides: Any) -> Any:
        """The variant's parameters, with ``overrides`` on top (unknown fields are refused)."""
        cls = self.params_class()
        valid = self.field_names()
        unknown = sorted((set(self.overrides) | set(overrides)) - valid)
        if unknown:
            raise ValueError(
                f"tracker {self.name!r} has no parameter(s) {', '.join(unknown)}; "
                f"valid: {', '.join(sorted(valid))}"
            )
        return cls(**{**self.overrides, **overrides})

    def create(self, params: Any = None, **overrides: Any) -> Tracker:
        """A new tracker; ``params`` (an instance of :meth:`params_class`, or a mapping of its
        fields, validated like overrides) and/or overrides.

        Anything else is refused naming its type: a tracker built around a dict or another
        tracker's parameters would run unvalidated until something deep inside it failed.
        """
        cls = self.params_class()
        if params is None:
            params = self.make_params(**overrides)
        elif isinstance(params, Mapping):
            params = self.make_params(**{**params, **overrides})
        elif not isinstance(params, cls):
            raise ValueError(
                f"tracker {self.name!r} takes params as a {cls.__name__} or a mapping of its "
                f"fields, got {type(params).__name__}"
            )
        elif overrides:
            self.make_params(**overrides)  # unknown fields are refused by name
            params = replace(params, **overrides)
        trk = self.tracker_class()(params)
        trk.name = self.name  # a variant's own name (bqp-ncc), in reports and messages
        return trk


def entry(name: str, target: str, params: str, summary: str = "", **overrides: Any) -> TrackerEntry:
    """A :class:`TrackerEntry`: the tracker ``target`` and its parameter dataclass ``params``
    (both ``"module:Class"``, imported on use), with ``overrides`` making the variant.

    >>> entry("ncc-wide", "tracker.baselines.ncc:NCCTracker", "tracker.baselines.ncc:NCCParams",
    ...       search_factor=3.0).make_params().search_factor
    3.0
    """
    return TrackerEntry(name, target, params, MappingProxyType(overrides), summary)


_BQP = ("tracker.bqp.tracker:BQPTracker", "tracker.bqp.params:BQPParams")
_NCC = ("tracker.baselines.ncc:NCCTracker", "tracker.baselines.ncc:NCCParams")

TRACKERS: Mapping[str, TrackerEntry] = MappingProxyType(
    {
        e.name: e
        for e in (
            entry(
                "bqp", *_BQP, "BQP / Frank-Wolfe SWAP, KCF appearance, speed-up sampling (paper 1)"
            ),
            entry(
                "bqp-ncc",
                *_BQP,
                "BQP / Frank-Wolfe SWAP with NCC template appearance",
                appearance="ncc",
            ),
            entry(
                "bqp-dense",
                *_BQP,
                "BQP with dense candidates (no speed-up sampling)",
                speedup=False,
            ),
            entry("ncc", *_NCC, "independent NCC template tracker (baseline of both papers)"),
            entry(
                "pnmc",
                "tracker.pnmc.tracker:PNMCTracker",
                "tracker.pnmc.params:PNMCParams",
                "prominence + neighbourhood motion concurrence, hierarchical update (paper 2)",
            ),
            entry(
                "meanshift",
                "tracker.baselines.meanshift:MeanShiftTracker",
                "tracker.baselines.meanshift:MeanShiftParams",
                "OpenCV mean-shift on colour histograms (paper 2's MS)",
            ),
            entry(
                "bytetrack",
                "tracker.baselines.detection:ByteTrackTracker",
                "tracker.baselines.detection:ByteTrackParams",
                "ByteTrack on a detection feed (simulated head detections by default)",
            ),
            entry(
                "ocsort",
                "tracker.baselines.detection:OCSORTTracker",
                "tracker.baselines.detection:OCSORTParams",
                "OC-SORT on a detection feed (simulated head detections by default)",
            ),
        )
    }
)
"""Registry name -> :class:`TrackerEntry`, in the order tables list them."""


PLUGIN_GROUP = "crowdsim.trackers"
"""The entry-point group that installed packages declare their trackers under."""
_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.+-]{0,63}")
_TARGET = re.compile(r"[A-Za-z_][\w.]*:[A-Za-z_][\w.]*")
_REGISTERED: dict[str, TrackerEntry] = {}
_REGISTERING = threading.Lock()
"""Held while :func:`register` checks a name and adds it, and while :func:`unregister` drops
one: two threads registering one name never both succeed."""


def _check_entry(e: Any, origin: str) -> TrackerEntry:
    """``e`` if it is a well-formed entry whose classes import, else ``ValueError`` naming
    ``origin`` and the field."""
    if not isinstance(e, TrackerEntry):
        raise ValueError(
            f"{origin}: expected a tracker.registry.TrackerEntry (tracker.registry.entry(...)), "
            f"got {type(e).__name__}"
        )
    if not isinstance(e.name, str) or not _NAME.fullmatch(e.name):
        raise ValueError(
            f"{origin}: name must be 1-64 letters, digits or _.+- (starting with a letter or "
            f"digit), got {e.name!r}"
        )
    if e.name in TRACKERS:
        raise ValueError(f"{origin}: {e.name!r} is a built-in tracker; choose another name")
    for what in ("target", "params"):
        value = getattr(e, what)
        if not isinstance(value, str) or not _TARGET.fullmatch(value):
            raise ValueError(f"{origin}: {what} must be 'module:Class', got {value!r}")
        try:
            _load(value)
        except Exception as exc:  # noqa: BLE001 - any import failure, named
            raise ValueError(
                f"{origin}: {what} {value!r} does not import: {type(exc).__name__}: {exc}"
            ) from None
    cls = e.tracker_class()
    if not (isinstance(cls, type) and issubclass(cls, Tracker)):
        raise ValueError(f"{origin}: target {e.target!r} is not a tracker.base.Tracker subclass")
    if not is_dataclass(e.params_class()):
        raise ValueError(f"{origin}: params {e.params!r} is not a dataclass")
    try:  # its overrides name fields of its parameters, with valid values
        e.make_params()
    except ValueError:
        raise
    except Exception as exc:  # noqa: BLE001 - a required field, a TypeError in a check: named
        raise ValueError(
            f"{origin}: params {e.params!r} do not build from their defaults: "
            f"{type(exc).__name__}: {exc}"
        ) from None
    return e


def register(e: TrackerEntry) -> None:
    """Register ``e`` (made with :func:`entry`) in this process: :func:`get`,
    :func:`make_tracker` and the commands run in process see it; spawned workers do not (use
    an entry point, the module docstring). Its classes are imported and checked now; a name
    taken by a built-in, an entry point or an earlier :func:`register` is refused.
    """
    _check_entry(e, f"register({getattr(e, 'name', e)!r})")
    global _REGISTERED
    with _REGISTERING:
        if e.name in _REGISTERED or e.name in _plugins():
            raise ValueError(
                f"register: tracker {e.name!r} is already registered; unregister it first"
            )
        # a new dict, never one changed in place: names() in another thread reads a whole one
        _REGISTERED = {**_REGISTERED, e.name: e}


def unregister(name: str) -> None:
    """Forget a tracker added with :func:`register` (built-ins and entry points stay)."""
    global _REGISTERED
    with _REGISTERING:
        if name not in _REGISTERED:
            raise ValueError(f"unregister: {name!r} was not added with register()")
        _REGISTERED = {n: e for n, e in _REGISTERED.items() if n != name}


@functools.cache
def _plugins() -> Mapping[str, Any]:
    """Name -> entry point of the group :data:`PLUGIN_GROUP`, read once per process (the
    modules are imported only by :func:`_plugin`). Built-in names are left out."""
    from importlib.metadata import entry_points

    return MappingProxyType(
        {ep.name: ep for ep in entry_points(group=PLUGIN_GROUP) if ep.name not in TRACKERS}
    )


def _dist(ep: Any) -> str:
    """The name of the distribution that declares the entry point ``ep``."""
    return getattr(getattr(ep, "dist", None), "name", None) or "an installed package"


@functools.cache
def _plugin(name: str) -> TrackerEntry:
    ep = _plugins()[name]
    origin = f"tracker plug-in {name!r} ({ep.value}, entry point of {_dist(ep)})"
    try:
        obj = ep.load()
    except Exception as exc:  # noqa: BLE001 - any import failure, named
        raise ValueError(f"{origin} does not load: {type(exc).__name__}: {exc}") from None
    e = _check_entry(obj, origin)
    if e.name != name:
        raise ValueError(f"{origin} names itself {e.name!r}; the two must agree")
    return e


def names() -> tuple[str, ...]:
    """Registered tracker names: the built-ins, then :func:`register`'s, then the installed
    plug-ins' (read without importing them)."""
    reg = _REGISTERED  # one snapshot: register() swaps in a new dict
    return (*TRACKERS, *reg, *(n for n in _plugins() if n not in reg))


def get(name: str) -> TrackerEntry:
    """The entry named ``name``; ``ValueError`` listing the valid names otherwise (or naming
    the plug-in that does not load)."""
    if isinstance(name, str):
        if name in TRACKERS:
            return TRACKERS[name]
        reg = _REGISTERED
        if name in reg:
            return reg[name]
        if name in _plugins():
            return _plugin(name)
    raise ValueError(f"unknown tracker {name!r}; valid trackers: {', '.join(names())}")


def entries(plugins: bool = True) -> Mapping[str, TrackerEntry]:
    """Every tracker's entry by name (:func:`names`' order), plug-ins that do not load left
    out (:func:`get` names them and why); ``plugins=False``: the built-ins and
    :func:`register`'s alone, no installed plug-in imported."""
    if not plugins:
        return MappingProxyType({**TRACKERS, **_REGISTERED})
    out = {}
    for n in names():
        try:
            out[n] = get(n)
        except ValueError:
            continue
    return MappingProxyType(out)


def listing() -> str:
    """``"name: summary; ..."`` of every tracker, for ``--help``. Installed plug-ins are named
    with their distribution, never imported: every command builds its help, and a plug-in's
    import (slow, broken or with side effects) is for the command that asks for it."""
    own = entries(plugins=False)
    parts = [f"{n}: {e.summary}" for n, e in own.items()]
    for n, ep in _plugins().items():
        if n not in own:
            parts.append(f"{n}: a plug-in of {_dist(ep)}")
    return "; ".join(parts)


def make_tracker(tracker: str | Tracker, params: Any = None, **overrides: Any) -> Tracker:
    """Resolve ``tracker`` (a registry name, or a ready :class:`Tracker` passed through).

    >>> make_tracker("ncc", search_factor=3.0).params.search_factor
    3.0
    """
    if isinstance(tracker, Tracker):
        if params is not None or overrides:
            raise ValueError("pass params only with a tracker name, not with a tracker object")
        return tracker
    return get(tracker).create(params, **overrides)
