"""The import layers of ``../shared/ARCHITECTURE.md``, checked by walking the source with ``ast``.

Rules (an import inside ``if TYPE_CHECKING:`` is for type checkers only and is not counted):

1. ``tracker/`` imports from ``crowdsim`` only the shared base (``crowdsim.atomic``,
   ``crowdsim.checks``, ``crowdsim.plotting``, ``crowdsim.progress``), never the simulator,
   the renderer, ``synth_data`` or ``envs``.
2. The simulator never imports the renderer.
3. ``synth_data/`` never imports ``tracker/``.
4. ``envs/`` never imports the application layer (``crowdsim.cli``, ``crowdsim.commands``,
   ``crowdsim.bench``).
5. No library module imports the application layer; no command re-enters the CLI.
6. Importing ``envs`` imports nothing heavy (registrations only).
"""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("crowdsim", "tracker", "synth_data", "envs")
SHARED_BASE = {
    "crowdsim",
    "crowdsim.atomic",
    "crowdsim.checks",
    "crowdsim.plotting",
    "crowdsim.progress",
}
SIMULATOR = {
    "crowdsim.world",
    "crowdsim.params",
    "crowdsim.forces",
    "crowdsim.scenarios",
    "crowdsim.simulation",
    "crowdsim.trajectories",
    "crowdsim.validation",
}
RENDERER = {"crowdsim.camera", "crowdsim.appearance_model", "crowdsim.render"}
APPLICATION = ("crowdsim.cli", "crowdsim.commands", "crowdsim.bench", "crowdsim.__main__")


def _module_name(path: Path, root: Path = ROOT) -> str:
    parts = list(path.relative_to(root).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def _is_type_checking(node: ast.If) -> bool:
    t = node.test
    return (isinstance(t, ast.Name) and t.id == "TYPE_CHECKING") or (
        isinstance(t, ast.Attribute) and t.attr == "TYPE_CHECKING"
    )


def imports_of(path: Path, root: Path = ROOT) -> list[tuple[int, str]]:
    """``(line, module)`` of every runtime import in ``path`` (relative ones resolved)."""
    tree = ast.parse(path.read_text(), str(path))
    here = _module_name(path, root).split(".")
    if path.name != "__init__.py":
        here = here[:-1]
    out: list[tuple[int, str]] = []

    def visit(node: ast.AST) -> None:
        for child in ast.iter_child_nodes(node):
            if isinstance(child, ast.If) and _is_type_checking(child):
                for sub in child.orelse:
                    visit(sub)
                continue
            if isinstance(child, ast.Import):
                out.extend((child.lineno, a.name) for a in child.names)
            elif isinstance(child, ast.ImportFrom):
                base = child.module or ""
                if child.level:
                    pkg = here[: len(here) - child.level + 1]
                    base = ".".join(pkg + ([base] if base else []))
                out.append((child.lineno, base))
                out.extend((child.lineno, f"{base}.{a.name}") for a in child.names)
            visit(child)

    visit(tree)
    return out


def _within(module: str, prefixes) -> bool:
    return any(module == p or module.startswith(p + ".") for p in prefixes)


def _tracker_may_import(mod: str) -> bool:
    top = mod.split(".")[0]
    if top in ("synth_data", "envs"):
        return False
    if top != "crowdsim":
        return True
    # ``from crowdsim.checks import require_number`` gives crowdsim.checks.require_number
    return mod in SHARED_BASE or mod.rsplit(".", 1)[0] in SHARED_BASE - {"crowdsim"}


def violations(root: Path = ROOT) -> list[str]:
    """Every import that breaks a layer rule, as ``"rule N (...): file:line imports mod"``."""
    bad = []
    for pkg in PACKAGES:
        for path in sorted((root / pkg).rglob("*.py")):
            me = _module_name(path, root)
            application = _within(me, APPLICATION)
            for line, mod in imports_of(path, root):
                where = f"{path.relative_to(root)}:{line} imports {mod}"
                top = mod.split(".")[0]
                if top not in PACKAGES:
                    continue
                if me.startswith("tracker") and not _tracker_may_import(mod):
                    bad.append(f"rule 1 (tracker -> {mod}): {where}")
                if me in SIMULATOR and _within(mod, RENDERER):
                    bad.append(f"rule 2 (simulator -> renderer): {where}")
                if me.startswith("synth_data") and top == "tracker":
                    bad.append(f"rule 3 (synth_data -> tracker): {where}")
                if me.startswith("envs") and _within(mod, APPLICATION):
                    bad.append(f"rule 4 (envs -> application): {where}")
                if not application and _within(mod, APPLICATION):
                    bad.append(f"rule 5 (library -> application): {where}")
                if me.startswith("crowdsim.commands") and mod == "crowdsim.cli.main":
                    bad.append(f"rule 5 (a command re-enters the CLI): {where}")
    return bad


def test_import_layers():
    assert violations() == []


def test_checker_sees_each_rule(tmp_path):
    # the walker reports what it is meant to, in a fake tree (never in the real source)
    probes = {
        "tracker/probe.py": "from typing import TYPE_CHECKING\nimport crowdsim.render\n"
        "from crowdsim.checks import require_number\n"
        "if TYPE_CHECKING:\n    import synth_data.mot\n",
        "crowdsim/simulation.py": "from crowdsim.render import SceneRenderer\n",
        "synth_data/probe.py": "from tracker.metrics import evaluate\n",
        "envs/probe.py": "from crowdsim.bench import main\n",
        "crowdsim/render.py": "import crowdsim.commands.track\n",
        "crowdsim/commands/demo.py": "from crowdsim.cli import main\n",
    }
    for rel, text in probes.items():
        (tmp_path / rel).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / rel).write_text(text)
    found = "\n".join(violations(tmp_path))
    assert "rule 1 (tracker -> crowdsim.render): tracker/probe.py:2" in found
    assert "probe.py:3" not in found and "probe.py:5" not in found
    assert "rule 2 (simulator -> renderer): crowdsim/simulation.py:1" in found
    assert "rule 3 (synth_data -> tracker): synth_data/probe.py:1" in found
    assert "rule 4 (envs -> application): envs/probe.py:1" in found
    assert "rule 5 (library -> application): crowdsim/render.py:1" in found
    assert "rule 5 (a command re-enters the CLI): crowdsim/commands/demo.py:1" in found


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
        "crowdsim.simulation",
        "tracker.bqp.tracker",
        "synth_data.generate",
        "envs.crowd",
        "tracker.metrics",
        "crowdsim.plotting",
        "crowdsim.experiments",
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
