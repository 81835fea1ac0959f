"""The tuned parameters of a tracker as a box ``[-1, 1]^d``: one module for every tuner.

What a tuner may change is one row of :data:`TUNABLES` per tracker family (keyed by its
parameter class; registry variants such as ``bqp-ncc`` share their family's row):
:class:`ParamSpace` maps an action ``a`` in ``[-1, 1]^d`` to that tracker's parameters
(:class:`tracker.bqp.params.BQPParams`, :class:`tracker.pnmc.params.PNMCParams`,
:class:`tracker.baselines.ncc.NCCParams`) and back. The Gymnasium environments
(:mod:`envs.tracker_tuning`), Optuna (:meth:`ParamSpace.optuna_suggest`) and Ray Tune
(:meth:`ParamSpace.ray_search_space`) all use it, so a value found by one tuner means the
same thing to the others.

Each coordinate is **piecewise linear through the default**: ``a = -1`` gives the low end of the
range, ``a = 0`` the default, ``a = +1`` the high end::

    value(a) = default + a (default - low)   for a <= 0
    value(a) = default + a (high - default)  for a >= 0

so the all-zero action is exactly the paper's parameters (a policy initialised around a zero
mean starts from them, and CMA-ES starts there), and every range holds 0 where switching a
term off is meaningful (the ablation of the paper's Table 3 is reachable).

BQP (``bqp``, ``bqp-ncc``, ``bqp-dense``):

=====================  ======  ========  =====  ==========================================
name                   low     default   high   meaning (``BQPParams`` field)
=====================  ======  ========  =====  ==========================================
``zeta``               0       0.3       1.5    weight of the motion term ``c_m`` (Eq. 1)
``eta``                0       0.2       1.0    weight of neighbourhood motion ``c_nm``
``w_sp``               0       0.3       1.5    weight of spatial proximity ``C_sp``
``w_g``                0       1.0       3.0    weight of grouping ``C_g``
``update_threshold``   0       0.6       1.0    appearance-update confidence threshold
``search_factor``      1.5     2.0       3.0    search region, template sizes (extended)
``motion_sigma``       0.2     0.5       1.5    motion Gaussian sigma, templates (extended)
``kcf_learning_rate``  0.005   0.05      0.3    KCF model interpolation (extended)
=====================  ======  ========  =====  ==========================================

PNMC (``pnmc``): ``tau`` (0.5 / 0.9 / 0.99, the update-confidence threshold of Algorithm 2),
``prior_sigma`` (0.1 / 0.5 / 2, the NMC prior's sigma, template sizes), ``neighbour_radius``
(0.5 / 2.5 / 6, the neighbour graph's radius), ``update_threshold`` (0 / 0.8 / 1, template
refresh); extended: ``search_factor`` (1.5 / 2 / 3), ``flow_radius`` (0.25 / 0.75 / 2),
``weight_scale`` (0.5 / 1 / 30 px, the neighbour weights' length unit), ``flow_min_ncc``
(0.2 / 0.5 / 0.9), ``update_every`` (1 / 10 / 30 frames, rounded).

NCC (``ncc``): ``update_threshold`` (0 / 0.6 / 1), ``search_factor`` (1.5 / 2 / 3); extended:
``update_every`` (1 / 10 / 30, frames between template refreshes, rounded).

The defaults are the parameter classes' defaults (the papers' values; for BQP ``w_sp = 0.3``
as documented there); ``tests/envs/test_param_space.py`` holds every row to them.
Out-of-range actions are clipped to ``[-1, 1]``.

>>> space = ParamSpace()
>>> space.names
('zeta', 'eta', 'w_sp', 'w_g', 'update_threshold')
>>> p = space.to_params([0, 0, 0, 0, 0])
>>> (p.zeta, p.eta, p.w_sp, p.w_g, p.update_threshold)
(0.3, 0.2, 0.3, 1.0, 0.6)
>>> space.to_params([1, -1, 0.5, 0, 0]).zeta, space.to_params([1, -1, 0.5, 0, 0]).eta
(1.5, 0.0)
>>> space.to_action(space.to_params([0.25, -0.5, 0, 1, -1])).tolist()
[0.25, -0.5, 0.0, 1.0, -1.0]

:func:`load_params` reads a parameters file (``best_params.json`` of ``crowdsim tune``) back for
``crowdsim track --params`` and ``crowdsim heldout``.
"""

from __future__ import annotations

import json
import os
from collections.abc import Mapping
from dataclasses import dataclass, fields, is_dataclass, replace
from pathlib import Path
from types import MappingProxyType
from typing import Any

import numpy as np

from crowdsim.checks import require_number


@dataclass(frozen=True, kw_only=True)
class Tunable:
    """One tuned parameter: a field of a tracker's parameters, its range and its default.

    Attributes
    ----------
    name : str
        Field of the tracker's parameter class.
    low, default, high : float
        Range ``[low, high]`` and the value at action 0 (``low <= default <= high``,
        ``low < high``).
    doc : str
        One line for tables and ``--help``.
    integer : bool
        An integer field: values are rounded.
    """

    name: str
    low: float
    default: float
    high: float
    doc: str = ""
    integer: bool = False

    def __post_init__(self) -> None:
        owner = f"Tunable({self.name})"
        require_number(owner, "low", self.low)
        require_number(owner, "high", self.high, lo=self.low, lo_open=True)
        require_number(owner, "default", self.default, lo=self.low, hi=self.high)

    def value(self, a: np.ndarray) -> np.ndarray:
        """Parameter value(s) for action coordinate(s) ``a`` in ``[-1, 1]`` (clipped)."""
        a = np.clip(np.asarray(a, dtype=np.float64), -1.0, 1.0)
        v = np.where(
            a <= 0,
            self.default + a * (self.default - self.low),
            self.default + a * (self.high - self.default),
        )
        return np.rint(v) if self.integer else v

    def action(self, v: np.ndarray) -> np.ndarray:
        """Action coordinate(s) of parameter value(s) ``v`` (clipped into the range)."""
        v = np.clip(np.asarray(v, dtype=np.float64), self.low, self.high)
        below = self.default - self.low
        above = self.high - self.default
        neg = np.where(below > 0, (v - self.default) / (below if below > 0 else 1.0), 0.0)
        pos = np.where(above > 0, (v - self.default) / (above if above > 0 else 1.0), 0.0)
        return np.where(v <= self.default, neg, pos)


BASE_TUNABLES: tuple[Tunable, ...] = (
    Tunable(
        name="zeta", low=0.0, default=0.3, high=1.5, doc="weight of the motion term c_m (Eq. 1)"
    ),
    Tunable(
        name="eta",
        low=0.0,
        default=0.2,
        high=1.0,
        doc="weight of the neighbourhood-motion term c_nm (Eq. 1)",
    ),
    Tunable(
        name="w_sp",
        low=0.0,
        default=0.3,
        high=1.5,
        doc="weight of the spatial-proximity term C_sp (Eq. 1)",
    ),
    Tunable(
        name="w_g", low=0.0, default=1.0, high=3.0, doc="weight of the grouping term C_g (Eq. 1)"
    ),
    Tunable(
        name="update_threshold",
        low=0.0,
        default=0.6,
        high=1.0,
        doc="appearance model updated only at confidence >= this (Sec. 7.1)",
    ),
)
"""BQP's five tuned parameters: four term weights and the update threshold."""

EXTRA_TUNABLES: tuple[Tunable, ...] = (
    Tunable(
        name="search_factor",
        low=1.5,
        default=2.0,
        high=3.0,
        doc="side of the search region, template sizes",
    ),
    Tunable(
        name="motion_sigma",
        low=0.2,
        default=0.5,
        high=1.5,
        doc="sigma of the motion Gaussian (Eq. 6-7), template sizes",
    ),
    Tunable(
        name="kcf_learning_rate",
        low=0.005,
        default=0.05,
        high=0.3,
        doc="interpolation factor of the KCF model update",
    ),
)
"""BQP's tunables added by ``ParamSpace(extended=True)``."""


UPDATE_EVERY = Tunable(
    name="update_every",
    low=1,
    default=10,
    high=30,
    doc="frames between template refreshes",
    integer=True,
)
"""The template trackers' refresh period (PNMC and NCC both refresh every 10 frames by
default; paper 2, Sec. 4)."""

PNMC_TUNABLES: tuple[Tunable, ...] = (
    Tunable(
        name="tau",
        low=0.5,
        default=0.9,
        high=0.99,
        doc="update-confidence threshold tau: below it the flow prior, then a delayed update",
    ),
    Tunable(
        name="prior_sigma",
        low=0.1,
        default=0.5,
        high=2.0,
        doc="sigma of the neighbourhood-motion prior's Gaussians, template sizes (Eq. 1-2)",
    ),
    Tunable(
        name="neighbour_radius",
        low=0.5,
        default=2.5,
        high=6.0,
        doc="radius of the neighbour graph, template sizes (Sec. 3.4)",
    ),
    Tunable(
        name="update_threshold",
        low=0.0,
        default=0.8,
        high=1.0,
        doc="template refreshed only at update confidence >= this",
    ),
)
"""PNMC's tuned parameters (paper 2)."""

PNMC_EXTRA: tuple[Tunable, ...] = (
    Tunable(
        name="search_factor", low=1.5, default=2.0, high=3.0, doc="search region, template sizes"
    ),
    Tunable(
        name="flow_radius",
        low=0.25,
        default=0.75,
        high=2.0,
        doc="flow patches within this of a target are its neighbours, template sizes",
    ),
    Tunable(
        name="weight_scale",
        low=0.5,
        default=1.0,
        high=30.0,
        doc="length unit of the neighbour weights exp(-d / scale), px (Eq. 3; paper: 1)",
    ),
    Tunable(
        name="flow_min_ncc",
        low=0.2,
        default=0.5,
        high=0.9,
        doc="a flow patch below this NCC in any step is dropped",
    ),
    UPDATE_EVERY,
)

NCC_TUNABLES: tuple[Tunable, ...] = (
    Tunable(
        name="update_threshold",
        low=0.0,
        default=0.6,
        high=1.0,
        doc="template refreshed only at NCC peak >= this",
    ),
    Tunable(
        name="search_factor", low=1.5, default=2.0, high=3.0, doc="search region, template sizes"
    ),
)
"""The NCC baseline's tuned parameters."""

NCC_EXTRA: tuple[Tunable, ...] = (UPDATE_EVERY,)


@dataclass(frozen=True)
class TunableRow:
    """What a tuner may change in one tracker family: ``base`` always, ``extra`` with
    ``extended``."""

    base: tuple[Tunable, ...]
    extra: tuple[Tunable, ...] = ()


TUNABLES: Mapping[str, TunableRow] = MappingProxyType(
    {
        "tracker.bqp.params:BQPParams": TunableRow(BASE_TUNABLES, EXTRA_TUNABLES),
        "tracker.pnmc.params:PNMCParams": TunableRow(PNMC_TUNABLES, PNMC_EXTRA),
        "tracker.baselines.ncc:NCCParams": TunableRow(NCC_TUNABLES, NCC_EXTRA),
    }
)
"""The one table of what a tuner may change: tracker family (its parameter class, as the
registry names it) -> :class:`TunableRow`. Adding a tunable tracker is one row here."""


def extended_summary() -> str:
    """What ``extended`` adds, per tracker family, for ``--help`` texts.

    >>> extended_summary().split("; ")[0]
    'BQP: search_factor, motion_sigma, kcf_learning_rate'
    """
    return "; ".join(
        f"{key.rsplit(':', 1)[1].removesuffix('Params')}: " + ", ".join(t.name for t in row.extra)
        for key, row in TUNABLES.items()
    )


def _row_key(params_cls: type) -> str:
    return f"{params_cls.__module__}:{params_cls.__qualname__}"


class ParamSpace:
    """``[-1, 1]^d`` <-> a tracker's parameters (see the module docstring).

    Parameters
    ----------
    extended : bool
        Add the row's extra tunables (BQP: search factor, motion sigma, KCF learning rate,
        ``d = 8`` instead of 5).
    base : parameters, optional
        Values of every field that is not tuned, an instance of the tracker's parameter
        class. Its tuned fields are ignored: the action sets them. Default: ``tracker``'s
        registry parameters.
    tracker : str
        Registry name whose row of :data:`TUNABLES` is tuned when ``base`` is not given
        (default ``"bqp"``).

    Attributes
    ----------
    tunables : tuple of Tunable
    names : tuple of str
    low, high, default : (d,) float64
        Ranges and defaults in parameter units.
    dim : int
    """

    def __init__(self, extended: bool = False, base: Any = None, tracker: str = "bqp") -> None:
        from tracker.registry import get

        if base is None:
            require_tunable(tracker, "tracker")
            base = get(tracker).make_params()
        row = TUNABLES.get(_row_key(type(base))) if is_dataclass(base) else None
        if row is None:
            raise ValueError(
                "ParamSpace(base=...) must be the parameters of a tunable tracker "
                f"({', '.join(tunable_trackers())}), got {type(base).__name__}"
            )
        self.extended = bool(extended)
        self.base = base
        self.params_class = type(base)
        self.tunables = row.base + (row.extra if extended else ())
        self.names = tuple(t.name for t in self.tunables)
        self.low = np.array([t.low for t in self.tunables])
        self.high = np.array([t.high for t in self.tunables])
        self.default = np.array([t.default for t in self.tunables])
        self.dim = len(self.tunables)

    def __repr__(self) -> str:
        return (
            f"ParamSpace({self.params_class.__name__}, extended={self.extended}, "
            f"names={self.names})"
        )

    # ------------------------------------------------------------------ action <-> params
    def clip(self, action: Any) -> tuple[np.ndarray, int]:
        """``(clipped action (d,) float64, number of coordinates that were outside [-1, 1])``.

        An action of another shape, not real numbers, or with NaN or infinite coordinates is
        refused (``ValueError``): clipping cannot give those a meaning.
        """
        raw = np.asarray(action) if not isinstance(action, (dict, str, bytes)) else None
        if raw is None or raw.dtype.kind not in "biuf" or raw.shape != (self.dim,):
            what = f"shape {raw.shape} of {raw.dtype}" if raw is not None else repr(action)
            raise ValueError(
                f"action must be {self.dim} real numbers ({', '.join(self.names)}), got {what}"
            )
        a = raw.astype(np.float64)
        if not np.isfinite(a).all():
            raise ValueError(f"action must be finite, got {a.tolist()}")
        out = (a < -1.0) | (a > 1.0)
        return np.clip(a, -1.0, 1.0), int(out.sum())

    def values(self, action: Any) -> dict[str, Any]:
        """``{name: value}`` for an action (clipped into ``[-1, 1]``; integer fields as int)."""
        a, _ = self.clip(action)
        return self.typed({t.name: t.value(a[i]) for i, t in enumerate(self.tunables)})

    def typed(self, values: Mapping[str, Any]) -> dict[str, Any]:
        """``{name: value}`` of the tuned fields of ``values`` (a mapping with at least those
        names, e.g. an Optuna trial's ``params``), integer fields as ``int`` (rounded), the
        others as ``float``.

        >>> space = ParamSpace(extended=True, tracker="pnmc")
        >>> v = space.typed({**dict.fromkeys(space.names, 1.0), "update_every": 11.0})
        >>> v["update_every"], v["tau"]
        (11, 1.0)
        """
        return {
            t.name: int(round(float(values[t.name]))) if t.integer else float(values[t.name])
            for t in self.tunables
        }

    def to_params(self, action: Any) -> Any:
        """The tracker's parameters of ``action`` ``(d,)`` (clipped)."""
        return replace(self.base, **self.values(action))

    def to_action(self, params: Any) -> np.ndarray:
        """``(d,)`` float64 action of ``params`` (the tracker's parameters or a
        ``{name: value}`` mapping holding every tuned name); values outside a range map to its
        end (-1 or +1)."""
        if isinstance(params, Mapping):
            missing = [n for n in self.names if n not in params]
            if missing:
                raise ValueError(f"parameters lack {', '.join(missing)}")
            get = params.__getitem__
        else:

            def get(name: str) -> Any:
                return getattr(params, name)

        return np.array([float(t.action(float(get(t.name)))) for t in self.tunables])

    def params_from_dict(self, values: Mapping[str, Any]) -> Any:
        """The tracker's parameters from ``{field: value}`` (tuned names and any other field),
        validated by the parameter class itself; unknown names raise ``ValueError`` listing the
        valid ones."""
        valid = {f.name for f in fields(self.params_class)}
        unknown = sorted(set(values) - valid)
        if unknown:
            raise ValueError(
                f"unknown {self.params_class.__name__} parameter(s) {', '.join(unknown)}; "
                f"valid: {', '.join(sorted(valid))}"
            )
        return replace(self.base, **dict(values))

    @property
    def default_action(self) -> np.ndarray:
        """The action of the paper defaults: ``zeros(d)``."""
        return np.zeros(self.dim)

    # ------------------------------------------------------------------ tuners
    def optuna_suggest(self, trial: Any) -> dict[str, Any]:
        """Suggest every tuned parameter in its own units (uniform over ``[low, high]``;
        integers for integer fields)."""
        return {
            t.name: (
                int(trial.suggest_int(t.name, int(t.low), int(t.high)))
                if t.integer
                else float(trial.suggest_float(t.name, t.low, t.high))
            )
            for t in self.tunables
        }

    def optuna_distributions(self) -> dict[str, Any]:
        """``{name: optuna distribution}`` (for ``enqueue_trial`` / ``add``)."""
        from optuna.distributions import FloatDistribution, IntDistribution

        return {
            t.name: (
                IntDistribution(int(t.low), int(t.high))
                if t.integer
                else FloatDistribution(t.low, t.high)
            )
            for t in self.tunables
        }

    def ray_search_space(self) -> dict[str, Any]:
        """``{name: ray.tune.uniform(low, high)}`` (``randint`` for integer fields) for Ray
        Tune's ``param_space``."""
        from ray import tune

        return {
            t.name: (
                tune.randint(int(t.low), int(t.high) + 1)
                if t.integer
                else tune.uniform(t.low, t.high)
            )
            for t in self.tunables
        }

    def describe(self) -> list[dict[str, Any]]:
        """JSON-ready table of the tunables (name, low, default, high, doc)."""
        return [
            {"name": t.name, "low": t.low, "default": t.default, "high": t.high, "doc": t.doc}
            for t in self.tunables
        ]

    def signature(self) -> str:
        """Short text naming the space (stored in studies so a foreign one is refused): the
        parameter class, then each tunable."""
        own = ";".join(f"{t.name}:{t.low:g}:{t.default:g}:{t.high:g}" for t in self.tunables)
        if self.params_class.__name__ == "BQPParams":
            return own  # BQP studies written before other trackers could be tuned stay valid
        return f"{self.params_class.__name__};{own}"


def tunable_trackers(plugins: bool = True) -> tuple[str, ...]:
    """Registry names whose family has a row of :data:`TUNABLES` (``plugins=False``: without
    importing the installed plug-ins, for ``--help``; one built on a tunable family's
    parameters is tunable all the same)."""
    from tracker.registry import entries

    return tuple(n for n, e in entries(plugins).items() if e.params in TUNABLES)


def require_tunable(tracker: Any, flag: str = "--tracker") -> str:
    """``tracker`` if it names a tracker the tuning layer supports; ``ValueError`` naming
    ``flag`` and the supported names otherwise (unknown names list every registered one)."""
    from tracker.registry import get

    if get(tracker).params not in TUNABLES:  # an unknown name lists the registered trackers
        raise ValueError(
            f"{flag} {tracker}: no row of tunables for this tracker in "
            f"envs.param_space.TUNABLES (tunable: {', '.join(tunable_trackers())})"
        )
    return tracker


def read_json(path: str | os.PathLike[str], what: str) -> Any:
    """The JSON document in ``path``; ``ValueError`` naming the file (and ``what`` it should
    be) when it is binary, not UTF-8 or not valid JSON. A missing file raises ``OSError``."""
    p = Path(path)
    if p.is_dir():
        raise ValueError(f"{p}: is a folder, not {what}")
    raw = p.read_bytes()
    try:
        return json.loads(raw.decode("utf-8"))
    except UnicodeDecodeError:
        raise ValueError(f"{p}: not {what} (binary, not UTF-8 text)") from None
    except json.JSONDecodeError as exc:
        raise ValueError(f"{p}: not {what} (invalid JSON: {exc})") from None


def load_params(path: str | os.PathLike[str]) -> tuple[str, Any]:
    """``(tracker name, parameters)`` from a ``best_params.json`` written by
    :func:`envs.tuners.tune` (or any JSON object ``{"params": {field: value}}`` /
    ``{field: value}``, optionally with ``"tracker": NAME``; default ``bqp``).

    Every problem -- a binary or broken file, an unknown tracker, an unknown or out-of-range
    parameter -- raises ``ValueError`` naming the file.
    """
    from tracker.registry import get

    p = Path(path)
    doc = read_json(p, "a parameters file (JSON)")
    if not isinstance(doc, dict):
        raise ValueError(f"{p}: expected a JSON object of parameters, got {type(doc).__name__}")
    name = doc.get("tracker", "bqp")
    values = doc.get("params", doc)
    if not isinstance(values, dict):
        raise ValueError(f"{p}: 'params' must be an object of parameter values")
    values = {k: v for k, v in values.items() if k not in ("tracker", "format")}
    try:
        entry = get(name)
        row = TUNABLES.get(_row_key(entry.params_class()))
        for t in () if row is None else row.base + row.extra:
            v = values.get(t.name)
            # files of releases that wrote tuned integer fields as floats (11.0)
            if t.integer and isinstance(v, float) and v.is_integer():
                values[t.name] = int(v)
        return name, entry.make_params(**values)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{p}: {exc}") from None


def candidate_actions(space: ParamSpace, m: int, seed: int = 0) -> np.ndarray:
    """``(m, d)`` actions: row 0 the defaults (all zeros), then ``m - 1`` points of a seeded,
    scrambled Sobol sequence over ``[-1, 1]^d``."""
    require_number("headroom", "candidates", m, lo=1, hi=1024, integer=True)
    from scipy.stats import qmc

    out = np.zeros((m, space.dim))
    if m > 1:
        sobol = qmc.Sobol(space.dim, scramble=True, seed=seed)
        pts = sobol.random(1 << int(np.ceil(np.log2(m - 1))))[: m - 1]
        out[1:] = 2.0 * pts - 1.0
    return out
