"""Optional stacks: one :func:`require` for every import of an extra, one error for a missing one.

Torch and stable-baselines3 (``rl``), Ray (``distributed``), the ``trackers`` package of
ByteTrack / OC-SORT (``detect``), the peer simulators and QP solvers of the benchmarks
(``bench``) are extras of ``pyproject.toml``. Code that needs one calls
``require(module, extra, what)`` at the point of use, never at import, so a plain install imports
every module; a missing stack raises :class:`DependencyNotInstalled` with the exact install line.

It lives on the ground floor (base) because the tracker (``trackers``, Clarabel / OSQP), the jobs
runner (Ray), the environments and the benchmarks all use it, and the layer rules let every one of
them import the base, but none of the lower ones import ``envs``.

>>> require("json", "rl", "a doctest").__name__
'json'
>>> try:
...     require("no_such_module", "rl", "crowdsim train")
... except DependencyNotInstalled as exc:
...     print(exc)
crowdsim train needs no_such_module, which is not installed: pip install 'crowdsim[rl]'
"""

from __future__ import annotations

import importlib
from types import ModuleType

EXTRAS: dict[str, str] = {
    "rl": "stable-baselines3, the CPU build of torch and cmaes (train, --policy, CMA-ES)",
    "distributed": "Ray and Ray Tune (--backend ray)",
    "detect": "the CPU build of torch (head detector) and the trackers package (ByteTrack / "
    "OC-SORT)",
    "bench": "JuPedSim, PySocialForce, Clarabel and OSQP (crowdsim bench)",
}
"""Every extra a :func:`require` may name, with what it brings (``tests/test_packaging.py``
checks that each one is an extra of ``pyproject.toml``)."""


class DependencyNotInstalled(ImportError, ValueError):
    """An optional stack is missing; the message ends with the ``pip install`` line.

    An ``ImportError`` (what the missing import is) and a ``ValueError`` (so the ``crowdsim``
    command reports it in one line, exit 2, like any other input it cannot act on).
    """


def install_line(extra: str) -> str:
    """``pip install 'crowdsim[EXTRA]'`` for a known extra; ``ValueError`` for any other."""
    if extra not in EXTRAS:
        raise ValueError(f"unknown extra {extra!r}; the extras are {sorted(EXTRAS)}")
    return f"pip install 'crowdsim[{extra}]'"


def require(module: str, extra: str, what: str) -> ModuleType:
    """Import ``module`` (a third-party package) or raise :class:`DependencyNotInstalled`.

    Parameters
    ----------
    module : str
        Dotted module name, e.g. ``"stable_baselines3"`` or ``"ray.tune"``.
    extra : str
        The extra of ``pyproject.toml`` that installs it (a key of :data:`EXTRAS`).
    what : str
        What needs it, as the user asked for it (``"crowdsim train"``, ``"--backend ray"``).
    """
    line = install_line(extra)
    try:
        return importlib.import_module(module)
    except ImportError as exc:
        missing = exc.name or module.split(".")[0]
        raise DependencyNotInstalled(
            f"{what} needs {missing}, which is not installed: {line}", name=missing
        ) from None
