"""The import layers of ``../shared/ARCHITECTURE.md``, checked by walking the source with ``ast``.

Every module of the four packages is a node; every ``import`` is an edge, lazy ones (inside a
function) included, and so is every target of a string registry. An import inside
``if TYPE_CHECKING:`` is for type checkers only and is not counted. The rules:

1. **Every ``crowdsim`` module is classified** as base, sim, render, lab or app (:func:`layer`).
   ``crowdsim.trajectories`` is base: it is the data contract the simulator writes and the
   renderer reads, and imports only base itself. ``crowdsim.detections`` is base for the same
   reason: the detections type that detectors (``synth_data``) produce and ``tracker`` reads.
2. **The floors** (:data:`FORBIDDEN`): base imports nothing above it; sim and render import only
   base (and each other never); none of them imports ``tracker``, ``synth_data``, ``envs`` or
   the lab; ``tracker`` imports from ``crowdsim`` only base and never ``synth_data`` or
   ``envs``; ``synth_data`` never imports ``tracker``, ``envs`` or the lab; the lab and
   ``envs`` never import the application (``crowdsim.cli``, ``crowdsim.commands``,
   ``crowdsim.bench``).
3. **No command re-enters the CLI**: any import of ``crowdsim.cli`` from a command or a
   benchmark fails.
4. **No dynamic import of a project module**: ``importlib.import_module``, ``__import__``,
   ``runpy`` and spec loaders are refused, except in the string registries of
   :data:`REGISTRIES` (whose targets the test reads and adds to the graph) and in
   :mod:`crowdsim.optional`, whose ``require(module, ...)`` calls must each name a third-party
   module literally.
5. **Registry targets** are strings under the registry's own package: ``tracker.*`` for the
   tracker registry and for the tunables' parameter classes (``envs.param_space``),
   ``envs.*`` for the Gymnasium table, ``crowdsim.bench.*`` for the benchmarks; each must
   name an existing module and attribute (a ``"module:Class"`` outside the project breaks
   the rule too).
6. **No import cycle**, lazy imports and registry targets included.
7. Importing a library module sets no environment variable and selects no matplotlib backend;
   importing ``envs`` imports nothing heavy (subprocess tests below).

Each rule has a self-test that plants a violation into the real tree (an overlay, nothing is
written) and checks that :func:`violations` reports it.
"""

from __future__ import annotations

import ast
import re
import subprocess
import sys
from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("crowdsim", "tracker", "synth_data", "envs")

CROWDSIM_LAYERS: dict[str, frozenset[str]] = {
    "base": frozenset(
        {
            "crowdsim",
            "crowdsim.atomic",
            "crowdsim.checks",
            "crowdsim.detections",
            "crowdsim.events",
            "crowdsim.jobs",
            "crowdsim.optional",
            "crowdsim.plotting",
            "crowdsim.progress",
            "crowdsim.trajectories",
        }
    ),
    "sim": frozenset(
        {
            "crowdsim.decomposition",
            "crowdsim.forces",
            "crowdsim.params",
            "crowdsim.scenarios",
            "crowdsim.simulation",
            "crowdsim.validation",
            "crowdsim.world",
        }
    ),
    "render": frozenset(
        {"crowdsim.appearance_model", "crowdsim.camera", "crowdsim.knobs", "crowdsim.render"}
    ),
}
"""The ground floor, module by module: a new module must be placed here (rule 1)."""
LAB = ("crowdsim.lab",)
APP = ("crowdsim.cli", "crowdsim.__main__", "crowdsim.commands", "crowdsim.bench")
COMMANDS = ("crowdsim.commands", "crowdsim.bench")

FORBIDDEN: dict[str, frozenset[str]] = {
    "base": frozenset({"sim", "render", "lab", "app", "tracker", "synth_data", "envs"}),
    "sim": frozenset({"render", "lab", "app", "tracker", "synth_data", "envs"}),
    "render": frozenset({"sim", "lab", "app", "tracker", "synth_data", "envs"}),
    "tracker": frozenset({"sim", "render", "lab", "app", "synth_data", "envs"}),
    "synth_data": frozenset({"lab", "app", "tracker", "envs"}),
    "lab": frozenset({"app"}),
    "envs": frozenset({"app"}),
    "app": frozenset(),
}
"""Layers a module of each layer must not import (rule 2)."""

REGISTRIES: dict[str, str] = {
    "tracker.registry": "tracker.",
    "envs": "envs.",
    "crowdsim.bench": "crowdsim.bench.",
    "envs.param_space": "tracker.",  # TUNABLES: keyed by the trackers' parameter classes
}
"""Modules that hold a string registry, and the package its targets must live in (rule 5)."""
OPTIONAL = "crowdsim.optional"
"""The one module that imports by a computed name: third-party stacks, named by each caller."""

_TARGET = re.compile(r"^(crowdsim|tracker|synth_data|envs)(\.\w+)+(:\w+)?$")
_ANY_TARGET = re.compile(r"^[A-Za-z_]\w*(\.\w+)*:[A-Za-z_]\w*$")
"""A ``"module:Class"`` target of any package: one outside the project breaks rule 5 too."""
_DYNAMIC = {"import_module", "__import__", "run_module", "run_path", "spec_from_file_location"}


def _within(module: str, prefixes: tuple[str, ...]) -> bool:
    return any(module == p or module.startswith(p + ".") for p in prefixes)


def layer(module: str) -> str | None:
    """The layer of a project module: a crowdsim floor, ``tracker``, ``synth_data``, ``envs``."""
    top = module.split(".")[0]
    if top != "crowdsim":
        return top
    for name, members in CROWDSIM_LAYERS.items():
        if module in members:
            return name
    if _within(module, LAB):
        return "lab"
    if _within(module, APP):
        return "app"
    return None


@dataclass(frozen=True)
class Edge:
    line: int
    target: str
    """The module imported (resolved to the longest project module, for project targets)."""
    kind: str
    """``"import"``, ``"lazy"`` (inside a function), ``"registry"`` or ``"dynamic"``."""
    detail: str = ""


def _module_name(rel: Path) -> str:
    parts = list(rel.with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def _is_type_checking(node: ast.If) -> bool:
    t = node.test
    return (isinstance(t, ast.Name) and t.id == "TYPE_CHECKING") or (
        isinstance(t, ast.Attribute) and t.attr == "TYPE_CHECKING"
    )


def _call_name(func: ast.expr) -> str:
    if isinstance(func, ast.Name):
        return func.id
    if isinstance(func, ast.Attribute):
        return func.attr
    return ""


def _literal(node: ast.expr | None) -> str | None:
    return node.value if isinstance(node, ast.Constant) and isinstance(node.value, str) else None


class Tree:
    """The project's modules (``rel path -> source``), with planted files laid over."""

    def __init__(self, root: Path = ROOT, plant: Mapping[str, str] | None = None) -> None:
        self.sources: dict[str, str] = {}
        for pkg in PACKAGES:
            for path in sorted((root / pkg).rglob("*.py")):
                self.sources[str(path.relative_to(root))] = path.read_text()
        self.sources.update(plant or {})
        self.modules = {_module_name(Path(rel)): rel for rel in self.sources}

    def resolve(self, name: str) -> str | None:
        """The longest project module that ``name`` (a dotted import target) lies in."""
        parts = name.split(".")
        while parts:
            if ".".join(parts) in self.modules:
                return ".".join(parts)
            parts.pop()
        return None

    def edges(self, module: str) -> Iterator[Edge]:
        rel = self.modules[module]
        tree = ast.parse(self.sources[rel], rel)
        here = module.split(".")
        if not rel.endswith("__init__.py"):
            here = here[:-1]
        yield from self._walk(tree, here, lazy=False)

    def _walk(self, node: ast.AST, here: list[str], lazy: bool) -> Iterator[Edge]:
        for child in ast.iter_child_nodes(node):
            if isinstance(child, ast.If) and _is_type_checking(child):
                for sub in child.orelse:
                    yield from self._walk(sub, here, lazy)
                continue
            kind = "lazy" if lazy else "import"
            if isinstance(child, ast.Import):
                for a in child.names:
                    yield Edge(child.lineno, a.name, kind)
            elif isinstance(child, ast.ImportFrom):
                base = child.module or ""
                if child.level:
                    pkg = here[: len(here) - child.level + 1]
                    base = ".".join(pkg + ([base] if base else []))
                for a in child.names:  # a submodule when it is one, else the module itself
                    yield Edge(child.lineno, f"{base}.{a.name}", kind)
            elif isinstance(child, ast.Call) and _call_name(child.func) in _DYNAMIC:
                arg = _literal(child.args[0]) if child.args else None
                yield Edge(child.lineno, arg or "?", "dynamic", ast.unparse(child)[:60])
            elif isinstance(child, ast.Call) and _call_name(child.func) == "require":
                arg = _literal(child.args[0]) if child.args else None
                yield Edge(child.lineno, arg or "?", "require", ast.unparse(child)[:60])
            inner = lazy or isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda))
            yield from self._walk(child, here, inner)

    def registry_targets(self, module: str) -> Iterator[tuple[int, str]]:
        """``(line, "module[:attr]")`` of every target string in a registry module: the
        project's, and any other package's ``"module:Class"``."""
        tree = ast.parse(self.sources[self.modules[module]])
        # the entry-point group's name ("crowdsim.trackers") reads like a module and is none
        group = {
            id(node.value)
            for node in ast.walk(tree)
            if isinstance(node, ast.Assign)
            and [getattr(t, "id", None) for t in node.targets] == ["PLUGIN_GROUP"]
        }
        for node in ast.walk(tree):
            text = _literal(node) if isinstance(node, ast.Constant) else None
            if text and id(node) not in group and (_TARGET.match(text) or _ANY_TARGET.match(text)):
                yield node.lineno, text

    def defines(self, module: str, attr: str) -> bool:
        tree = ast.parse(self.sources[self.modules[module]])
        for node in tree.body:
            if isinstance(node, (ast.ClassDef, ast.FunctionDef)) and node.name == attr:
                return True
            if isinstance(node, (ast.Assign, ast.AnnAssign)):
                targets = node.targets if isinstance(node, ast.Assign) else [node.target]
                if any(isinstance(t, ast.Name) and t.id == attr for t in targets):
                    return True
        return False


def graph(tree: Tree) -> tuple[dict[str, list[tuple[str, Edge]]], list[str]]:
    """``module -> [(target module, edge)]`` over project modules, and the violations of rules
    4 and 5 found while building it (dynamic imports, registry targets)."""
    out: dict[str, list[tuple[str, Edge]]] = {}
    bad: list[str] = []
    for me, rel in tree.modules.items():
        deps = out.setdefault(me, [])
        for e in tree.edges(me):
            where = f"{rel}:{e.line}"
            if e.kind == "require":
                if e.target == "?" or e.target.split(".")[0] in PACKAGES:
                    bad.append(f"rule 4 (require() must name a third-party module): {where}")
                continue
            if e.kind == "dynamic":
                allowed = me in REGISTRIES or me == OPTIONAL
                if not allowed or e.target.split(".")[0] in PACKAGES:
                    bad.append(f"rule 4 (dynamic import {e.detail}): {where}")
                continue
            target = tree.resolve(e.target)
            if target is not None and target != me:
                deps.append((target, e))
        if me in REGISTRIES:
            prefix = REGISTRIES[me]
            for line, text in tree.registry_targets(me):
                mod, _, attr = text.partition(":")
                where = f"{rel}:{line}"
                if not mod.startswith(prefix):
                    bad.append(f"rule 5 (registry target {text!r} is not {prefix}*): {where}")
                    continue
                if mod not in tree.modules or (attr and not tree.defines(mod, attr)):
                    bad.append(f"rule 5 (registry target {text!r} does not exist): {where}")
                    continue
                deps.append((mod, Edge(line, mod, "registry")))
    return out, bad


def cycles(g: Mapping[str, list[tuple[str, Edge]]]) -> list[list[str]]:
    """Every import cycle (Tarjan's strongly connected components), each as one loop."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    found: list[list[str]] = []
    sys.setrecursionlimit(max(10_000, sys.getrecursionlimit()))

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w, _ in g.get(v, ()):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                found.append(sorted(comp))

    for v in sorted(g):
        if v not in index:
            visit(v)
    return found


def violations(root: Path = ROOT, plant: Mapping[str, str] | None = None) -> list[str]:
    """Every break of a layer rule, as ``"rule N (...): file:line ..."``."""
    tree = Tree(root, plant)
    g, bad = graph(tree)
    for me, rel in sorted(tree.modules.items()):
        mine = layer(me)
        if mine is None:
            bad.append(f"rule 1 (unclassified crowdsim module {me}): {rel}")
            continue
        for target, e in g[me]:
            where = f"{rel}:{e.line} imports {target}" + (" (lazily)" if e.kind == "lazy" else "")
            theirs = layer(target)
            if theirs in FORBIDDEN[mine]:
                bad.append(f"rule 2 ({mine} -> {theirs}): {where}")
            if _within(me, COMMANDS) and target == "crowdsim.cli":
                bad.append(f"rule 3 (a command re-enters the CLI): {where}")
    for loop in cycles(g):
        bad.append(f"rule 6 (import cycle): {' -> '.join(loop)}")
    return bad


def test_import_layers():
    assert violations() == []


PLANTED = {
    "rule 1 (unclassified crowdsim module crowdsim.crowd_flow)": {
        "crowdsim/crowd_flow.py": "import numpy\n"
    },
    "rule 2 (sim -> tracker): crowdsim/forces.py": {
        "crowdsim/forces.py": "def f():\n    from tracker.metrics import evaluate\n"
    },
    "rule 2 (render -> synth_data): crowdsim/render.py:1": {
        "crowdsim/render.py": "import synth_data.mot\n"
    },
    "rule 2 (sim -> render): crowdsim/simulation.py:1": {
        "crowdsim/simulation.py": "from crowdsim.render import SceneRenderer\n"
    },
    "rule 2 (base -> envs): crowdsim/checks.py:1": {"crowdsim/checks.py": "import envs\n"},
    "rule 2 (base -> sim): crowdsim/jobs.py:1": {
        "crowdsim/jobs.py": "from crowdsim.simulation import Simulation\n"
    },
    "rule 2 (tracker -> render): tracker/probe.py:2": {
        "tracker/probe.py": "from typing import TYPE_CHECKING\nimport crowdsim.render\n"
        "if TYPE_CHECKING:\n    import synth_data.mot\n"
    },
    "rule 2 (tracker -> synth_data): tracker/probe.py:1": {
        "tracker/probe.py": "from synth_data import mot\n"
    },
    "rule 2 (synth_data -> tracker): synth_data/probe.py:1": {
        "synth_data/probe.py": "from tracker.metrics import evaluate\n"
    },
    "rule 2 (synth_data -> envs): synth_data/probe.py:1": {
        "synth_data/probe.py": "import envs.episodes\n"
    },
    "rule 2 (envs -> app): envs/probe.py:1": {"envs/probe.py": "from crowdsim.bench import main\n"},
    "rule 2 (lab -> app): crowdsim/lab/probe.py:2": {
        "crowdsim/lab/probe.py": "def f():\n    from crowdsim.commands import track\n"
    },
    "rule 3 (a command re-enters the CLI): crowdsim/commands/probe.py:1": {
        "crowdsim/commands/probe.py": "import crowdsim.cli\n"
    },
    "rule 3 (a command re-enters the CLI): crowdsim/commands/other.py:2": {
        "crowdsim/commands/other.py": "def f():\n    from crowdsim import cli\n"
    },
    "rule 4 (dynamic import importlib.import_module('crowdsim.render')": {
        "tracker/probe.py": "import importlib\nR = importlib.import_module('crowdsim.render')\n"
    },
    "rule 4 (dynamic import __import__(name)": {
        "synth_data/probe.py": "def f(name):\n    return __import__(name)\n"
    },
    "rule 4 (require() must name a third-party module): tracker/probe.py:3": {
        "tracker/probe.py": "from crowdsim.optional import require\n\n"
        "require('synth_data', 'rl', 'x')\n"
    },
    "rule 5 (registry target 'crowdsim.render:SceneRenderer' is not tracker.*)": {
        "tracker/registry.py": "T = {'x': 'crowdsim.render:SceneRenderer'}\n",
    },
    "rule 5 (registry target 'cvtrack.tracker:CVTracker' is not tracker.*)": {
        "tracker/registry.py": "T = {'x': 'cvtrack.tracker:CVTracker'}\n",  # outside the tree
    },
    "rule 5 (registry target 'tracker.bqp.tracker:NoSuchTracker' does not exist)": {
        "tracker/registry.py": "T = {'x': 'tracker.bqp.tracker:NoSuchTracker'}\n",
    },
    "rule 6 (import cycle): synth_data.a -> synth_data.b": {
        "synth_data/a.py": "import synth_data.b\n",
        "synth_data/b.py": "def f():\n    import synth_data.a\n",  # lazy: still a cycle
    },
    "rule 6 (import cycle): tracker.baselines.ncc -> tracker.registry": {
        # only through the registry's string target "tracker.baselines.ncc:NCCTracker"
        "tracker/baselines/ncc.py": "+def f():\n    from tracker.registry import get\n",
    },
}
"""Expected report -> files laid over the real tree (a leading ``+`` appends to the file)."""


def _overlay(files: Mapping[str, str]) -> dict[str, str]:
    return {
        rel: (ROOT / rel).read_text() + text[1:] if text.startswith("+") else text
        for rel, text in files.items()
    }


@pytest.mark.parametrize("expected", list(PLANTED))
def test_each_rule_reports_a_planted_violation(expected):
    found = violations(plant=_overlay(PLANTED[expected]))
    assert any(v.startswith(expected) for v in found), "\n".join(found) or "nothing found"


def test_type_checking_imports_and_third_party_require_are_not_violations():
    plant = {
        "tracker/probe.py": "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n"
        "    import synth_data.mot\nfrom crowdsim.optional import require\n"
        "def f():\n    return require('trackers', 'detect', 'ByteTrack')\n",
    }
    assert violations(plant=plant) == []


THIRD_PARTY = "gymnasium, pettingzoo, cv2, numba, pymunk, scipy.sparse, matplotlib"
"""Imported before the snapshot: some set variables at import themselves (gymnasium and
pettingzoo: PYGAME_HIDE_SUPPORT_PROMPT; OpenCV's wheel: QT_QPA_* and LD_LIBRARY_PATH)."""


@pytest.mark.parametrize(
    "module",
    [
        "envs",
        "tracker",
        "crowdsim",
        "synth_data",
        "crowdsim.render",
        "crowdsim.knobs",
        "crowdsim.simulation",
        "tracker.bqp.tracker",
        "synth_data.generate",
        "envs.crowd",
        "tracker.metrics",
        "crowdsim.plotting",
        "crowdsim.lab.experiments",
    ],
)
def test_import_sets_no_process_state(module):
    code = (
        f"import os, sys, {THIRD_PARTY}; import matplotlib as mpl; "
        "backend = mpl.rcParams._get_backend_or_none(); "
        f"before = dict(os.environ); import {module}; "
        "assert dict(os.environ) == before, set(os.environ.items()) ^ set(before.items()); "
        "assert 'matplotlib.pyplot' not in sys.modules; "
        "assert mpl.rcParams._get_backend_or_none() == backend"
    )
    subprocess.run([sys.executable, "-c", code], check=True, cwd=ROOT)


def test_importing_envs_registers_and_imports_nothing_heavy():
    code = (
        "import sys, gymnasium, envs; "
        "assert 'crowdsim/TrackerTuning-v0' in gymnasium.registry; "
        "heavy = {'torch', 'ray', 'optuna', 'stable_baselines3', 'pymunk', 'cv2', "
        "'tracker', 'synth_data'} & set(sys.modules); assert not heavy, heavy"
    )
    subprocess.run([sys.executable, "-c", code], check=True, cwd=ROOT)
