"""The tuned parameters of the BQP tracker as a box ``[-1, 1]^d``: one module for every tuner.

:class:`ParamSpace` maps an action ``a`` in ``[-1, 1]^d`` to :class:`tracker.bqp.params.BQPParams`
and back. The Gymnasium environments (:mod:`envs.tracker_tuning`), Optuna
(:meth:`ParamSpace.optuna_suggest`) and Ray Tune (:meth:`ParamSpace.ray_search_space`) all use
it, so a value found by one tuner means the same thing to the others.

Each coordinate is **piecewise linear through the default**: ``a = -1`` gives the low end of the
range, ``a = 0`` the default, ``a = +1`` the high end::

    value(a) = default + a (default - low)   for a <= 0
    value(a) = default + a (high - default)  for a >= 0

so the all-zero action is exactly the paper's parameters (a policy initialised around a zero
mean starts from them, and CMA-ES starts there), and every range holds 0 where switching a
term off is meaningful (the ablation of the paper's Table 3 is reachable).

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

The defaults are the :class:`~tracker.bqp.params.BQPParams` defaults (the paper's values, with
``w_sp = 0.3`` as documented there). Out-of-range actions are clipped to ``[-1, 1]``.

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
from dataclasses import dataclass, fields, replace
from pathlib import Path
from typing import Any

import numpy as np

from crowdsim.checks import require_number


@dataclass(frozen=True, kw_only=True)
class Tunable:
    """One tuned parameter: a ``BQPParams`` field, its range and its default.

    Attributes
    ----------
    name : str
        Field of :class:`tracker.bqp.params.BQPParams`.
    low, default, high : float
        Range ``[low, high]`` and the value at action 0 (``low <= default <= high``,
        ``low < high``).
    doc : str
        One line for tables and ``--help``.
    """

    name: str
    low: float
    default: float
    high: float
    doc: str = ""

    def __post_init__(self) -> None:
        owner = f"Tunable({self.name})"
        require_number(owner, "low", self.low)
        require_number(owner, "high", self.high, lo=self.low, lo_open=True)
        require_number(owner, "default", self.default, lo=self.low, hi=self.high)

    def value(self, a: np.ndarray) -> np.ndarray:
        """Parameter value(s) for action coordinate(s) ``a`` in ``[-1, 1]`` (clipped)."""
        a = np.clip(np.asarray(a, dtype=np.float64), -1.0, 1.0)
        return np.where(
            a <= 0,
            self.default + a * (self.default - self.low),
            self.default + a * (self.high - self.default),
        )

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
"""The five tuned parameters of issue 9: four term weights and the update threshold."""

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
"""Tunables added by ``ParamSpace(extended=True)``."""


class ParamSpace:
    """``[-1, 1]^d`` <-> :class:`~tracker.bqp.params.BQPParams` (see the module docstring).

    Parameters
    ----------
    extended : bool
        Add :data:`EXTRA_TUNABLES` (search factor, motion sigma, KCF learning rate): ``d = 8``
        instead of 5.
    base : BQPParams, optional
        Values of every field that is not tuned (default: ``BQPParams()``, KCF appearance).
        Its tuned fields are ignored: the action sets them.

    Attributes
    ----------
    tunables : tuple of Tunable
    names : tuple of str
    low, high, default : (d,) float64
        Ranges and defaults in parameter units.
    dim : int
    """

    def __init__(self, extended: bool = False, base: Any = None) -> None:
        from tracker.bqp.params import BQPParams

        if base is None:
            base = BQPParams()
        elif not isinstance(base, BQPParams):
            raise ValueError(
                "ParamSpace(base=...) must be the parameters of a BQP tracker "
                f"({', '.join(tunable_trackers())}: a BQPParams), got {type(base).__name__}"
            )
        self.extended = bool(extended)
        self.base = base
        self.tunables = BASE_TUNABLES + (EXTRA_TUNABLES if extended else ())
        self.names = tuple(t.name for t in self.tunables)
        self.low = np.array([t.low for t in self.tunables])
        self.high = np.array([t.high for t in self.tunables])
        self.default = np.array([t.default for t in self.tunables])
        self.dim = len(self.tunables)
        valid = {f.name for f in fields(BQPParams)}
        assert set(self.names) <= valid, "a Tunable names no BQPParams field"

    def __repr__(self) -> str:
        return f"ParamSpace(extended={self.extended}, names={self.names})"

    # ------------------------------------------------------------------ action <-> params
    def clip(self, action: Any) -> tuple[np.ndarray, int]:
        """``(clipped action (d,) float64, number of coordinates that were outside [-1, 1])``.

        NaN coordinates are refused (``ValueError``): clipping cannot give them a meaning.
        """
        a = np.asarray(action, dtype=np.float64).reshape(-1)
        if a.shape != (self.dim,):
            raise ValueError(
                f"action must have {self.dim} entries ({', '.join(self.names)}), "
                f"got shape {np.shape(action)}"
            )
        if np.isnan(a).any():
            raise ValueError(f"action has NaN entries: {a.tolist()}")
        out = (a < -1.0) | (a > 1.0)
        return np.clip(a, -1.0, 1.0), int(out.sum())

    def values(self, action: Any) -> dict[str, float]:
        """``{name: value}`` for an action (clipped into ``[-1, 1]``)."""
        a, _ = self.clip(action)
        return {t.name: float(t.value(a[i])) for i, t in enumerate(self.tunables)}

    def to_params(self, action: Any) -> Any:
        """The :class:`~tracker.bqp.params.BQPParams` of ``action`` ``(d,)`` (clipped)."""
        return replace(self.base, **self.values(action))

    def to_action(self, params: Any) -> np.ndarray:
        """``(d,)`` float64 action of ``params`` (a ``BQPParams`` or a ``{name: value}`` mapping
        holding every tuned name); values outside a range map to its end (-1 or +1)."""
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
        """``BQPParams`` from ``{field: value}`` (tuned names and any other field), validated
        by ``BQPParams`` itself; unknown names raise ``ValueError`` listing the valid ones."""
        from tracker.bqp.params import BQPParams

        valid = set(BQPParams.field_names())
        unknown = sorted(set(values) - valid)
        if unknown:
            raise ValueError(
                f"unknown BQP parameter(s) {', '.join(unknown)}; valid: {', '.join(sorted(valid))}"
            )
        return replace(self.base, **dict(values))

    @property
    def default_action(self) -> np.ndarray:
        """The action of the paper defaults: ``zeros(d)``."""
        return np.zeros(self.dim)

    # ------------------------------------------------------------------ tuners
    def optuna_suggest(self, trial: Any) -> dict[str, float]:
        """Suggest every tuned parameter in its own units (uniform over ``[low, high]``)."""
        return {t.name: float(trial.suggest_float(t.name, t.low, t.high)) for t in self.tunables}

    def optuna_distributions(self) -> dict[str, Any]:
        """``{name: optuna.distributions.FloatDistribution}`` (for ``enqueue_trial`` / ``add``)."""
        from optuna.distributions import FloatDistribution

        return {t.name: FloatDistribution(t.low, t.high) for t in self.tunables}

    def ray_search_space(self) -> dict[str, Any]:
        """``{name: ray.tune.uniform(low, high)}`` for Ray Tune's ``param_space``."""
        from ray import tune

        return {t.name: tune.uniform(t.low, t.high) for t in self.tunables}

    def describe(self) -> list[dict[str, Any]]:
        """JSON-ready table of the tunables (name, low, default, high, doc)."""
        return [
            {"name": t.name, "low": t.low, "default": t.default, "high": t.high, "doc": t.doc}
            for t in self.tunables
        ]

    def signature(self) -> str:
        """Short text naming the space (stored in studies so a foreign one is refused)."""
        return ";".join(f"{t.name}:{t.low:g}:{t.default:g}:{t.high:g}" for t in self.tunables)


def tunable_trackers() -> tuple[str, ...]:
    """Registry names whose tracker :class:`ParamSpace` tunes (the BQP variants)."""
    from tracker.bqp.tracker import BQPTracker
    from tracker.registry import TRACKERS

    return tuple(n for n, e in TRACKERS.items() if issubclass(e.tracker_class(), BQPTracker))


def require_tunable(tracker: Any, flag: str = "--tracker") -> str:
    """``tracker`` if it names a tracker the tuning layer supports; ``ValueError`` naming
    ``flag`` and the supported names otherwise (unknown names list every registered one)."""
    from tracker.registry import get

    get(tracker)  # an unknown name lists the registered trackers
    supported = tunable_trackers()
    if tracker not in supported:
        raise ValueError(
            f"{flag} {tracker}: tuning supports the BQP trackers only ({', '.join(supported)})"
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
        return name, entry.make_params(**values)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{p}: {exc}") from None
