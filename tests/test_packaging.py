"""One OpenCV build: the core install requires exactly one OpenCV distribution, and wherever
two are installed side by side (they share one ``cv2/`` folder) they carry the same version.

The OpenCV wheels (``opencv-python``, ``opencv-python-headless``, the ``-contrib`` variants)
all install the same ``cv2`` package; two of different versions leave ``cv2`` a mix of two
builds. ``trackeval`` (core: the CLEAR/IDF1/HOTA metrics), ``trackers`` (the ``detect`` extra)
and ``gymnasium[other]`` all require ``opencv-python``, so the core requires that one too.
"""

from __future__ import annotations

import importlib.metadata as md
import re
import sys
from pathlib import Path

import pytest
from packaging.requirements import Requirement
from packaging.utils import canonicalize_name

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

PYPROJECT = Path(__file__).resolve().parents[1] / "pyproject.toml"
OPENCV = re.compile(r"^opencv-(contrib-)?python(-headless)?$")


def _is_opencv(name: str) -> bool:
    return bool(OPENCV.match(canonicalize_name(name)))


def _project() -> dict:
    return tomllib.loads(PYPROJECT.read_text())["project"]


def _installed_requires(name: str) -> list[str]:
    try:
        return md.requires(name) or []
    except md.PackageNotFoundError:
        return []


def _closure(requirements: list[str], extras: frozenset[str] = frozenset()) -> set[str]:
    """Canonical names of every distribution ``requirements`` pull in, recursively, through
    the installed metadata (markers evaluated for this interpreter, ``extras`` only at the
    top level, as pip does)."""
    seen: set[str] = set()
    todo = [(r, extras) for r in requirements]
    while todo:
        text, active = todo.pop()
        req = Requirement(text)
        if req.marker is not None and not any(
            req.marker.evaluate({"extra": e}) for e in (active or {""})
        ):
            continue
        name = canonicalize_name(req.name)
        if name in seen:
            continue
        seen.add(name)
        todo.extend((r, frozenset(req.extras)) for r in _installed_requires(name))
    return seen


def test_core_requires_exactly_one_opencv_distribution():
    direct = [Requirement(r).name for r in _project()["dependencies"]]
    assert len([n for n in direct if _is_opencv(n)]) == 1, direct
    pulled = {n for n in _closure(_project()["dependencies"]) if _is_opencv(n)}
    assert len(pulled) == 1, f"the core install pulls several OpenCV builds: {sorted(pulled)}"


@pytest.mark.parametrize("extra", sorted(_project().get("optional-dependencies", {})))
def test_extras_add_no_other_opencv_distribution(extra):
    """Each extra's own requirements (installed ones followed down) name the core's build."""
    project = _project()
    core = {n for n in _closure(project["dependencies"]) if _is_opencv(n)}
    pulled = {n for n in _closure(project["optional-dependencies"][extra]) if _is_opencv(n)}
    assert pulled <= core, f"extra {extra!r} pulls {sorted(pulled - core)} beside {core}"


def test_installed_opencv_distributions_share_one_version():
    found = {
        canonicalize_name(d.metadata["Name"]): d.version
        for d in md.distributions()
        if d.metadata["Name"] and _is_opencv(d.metadata["Name"])
    }
    assert found, "no OpenCV distribution installed"
    assert len(set(found.values())) == 1, f"cv2 mixes OpenCV builds: {found}"


def test_every_extra_named_by_require_is_an_extra_of_pyproject():
    from crowdsim.optional import EXTRAS

    extras = set(_project()["optional-dependencies"])
    assert set(EXTRAS) <= extras, set(EXTRAS) - extras
    # and no install hint elsewhere names an extra by hand (one code path for the hint)
    hints = re.compile(r"crowdsim\[([a-z]+)\]")
    root = PYPROJECT.parent
    for pkg in ("crowdsim", "tracker", "envs", "synth_data"):
        for path in (root / pkg).rglob("*.py"):
            for extra in hints.findall(path.read_text()):
                assert extra in extras, f"{path}: names the extra {extra!r}, which does not exist"
