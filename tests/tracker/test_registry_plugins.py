"""Trackers from outside the package: :func:`tracker.registry.register` in process, and the
``crowdsim.trackers`` entry points that the CLI and its worker processes see."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from tracker import registry
from tracker.registry import entry, get, make_tracker, names, register, unregister

ROOT = Path(__file__).resolve().parents[2]
_NCC = ("tracker.baselines.ncc:NCCTracker", "tracker.baselines.ncc:NCCParams")


@pytest.fixture
def wide_ncc():
    e = entry("ncc-wide", *_NCC, "NCC with a wider search", search_factor=3.0)
    register(e)
    yield e
    unregister("ncc-wide")


def test_a_registered_tracker_is_found_made_and_listed(wide_ncc):
    assert get("ncc-wide") is wide_ncc
    assert names()[: len(registry.TRACKERS)] == tuple(registry.TRACKERS)
    assert names()[len(registry.TRACKERS)] == "ncc-wide"  # then register's, then plug-ins'
    assert "ncc-wide" in registry.entries(plugins=False)
    trk = make_tracker("ncc-wide", max_lost=7)
    assert (trk.name, trk.params.search_factor, trk.params.max_lost) == ("ncc-wide", 3.0, 7)
    assert "ncc-wide: NCC with a wider search" in registry.listing()
    with pytest.raises(ValueError, match="already registered"):
        register(wide_ncc)


def test_unregister_forgets_it():
    register(entry("ncc-gone", *_NCC))
    unregister("ncc-gone")
    with pytest.raises(ValueError, match="unknown tracker 'ncc-gone'"):
        get("ncc-gone")
    with pytest.raises(ValueError, match="was not added with register"):
        unregister("ncc")


@pytest.mark.parametrize(
    ("bad", "message"),
    [
        (entry("bqp", *_NCC), "'bqp' is a built-in tracker"),
        (entry("", *_NCC), "name must be"),
        (entry("a b", *_NCC), "name must be"),
        (entry("x", "tracker.baselines.ncc.NCCTracker", _NCC[1]), "target must be 'module:Class'"),
        (
            entry("x", "no_such_module_zz:T", _NCC[1]),
            "target 'no_such_module_zz:T' does not import",
        ),
        (entry("x", "tracker.baselines.ncc:NCCParams", _NCC[1]), "not a tracker.base.Tracker"),
        (entry("x", _NCC[0], "tracker.baselines.ncc:NCCTracker"), "is not a dataclass"),
        (entry("x", *_NCC, search_factr=3.0), "has no parameter"),
        (("x", *_NCC), "expected a tracker.registry.TrackerEntry"),
    ],
)
def test_a_bad_registration_is_refused_by_field(bad, message):
    with pytest.raises(ValueError, match=message):
        register(bad)
    assert "x" not in names()


PLUGIN = """
from tracker.registry import entry

ENTRY = entry("mine", "tracker.baselines.ncc:NCCTracker", "tracker.baselines.ncc:NCCParams",
              "my NCC variant", search_factor=2.5)
WRONG_NAME = entry("other", "tracker.baselines.ncc:NCCTracker", "tracker.baselines.ncc:NCCParams")
"""


def _plugin_env(tmp_path: Path, lines: str) -> dict[str, str]:
    """An environment whose interpreter sees an installed distribution ``myplug`` with the
    ``crowdsim.trackers`` entry points ``lines`` (what ``pip install`` of a package declaring
    them leaves: a module and a ``.dist-info`` folder)."""
    site = tmp_path / "site"
    (site / "myplug").mkdir(parents=True)
    (site / "myplug" / "__init__.py").write_text(PLUGIN)
    info = site / "myplug-0.1.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: myplug\nVersion: 0.1\n")
    (info / "entry_points.txt").write_text(f"[crowdsim.trackers]\n{lines}\n")
    return dict(os.environ, PYTHONPATH=os.pathsep.join([str(site), str(ROOT)]))


def _python(env: dict[str, str], code: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-c", code], env=env, capture_output=True, text=True, cwd=ROOT
    )


def test_an_entry_point_plugin_is_a_tracker_of_every_process(tmp_path):
    env = _plugin_env(
        tmp_path,
        "mine = myplug:ENTRY\nbroken = myplug_missing:ENTRY\nmisnamed = myplug:WRONG_NAME\n"
        "bqp = myplug:ENTRY",
    )
    code = """
import sys
from tracker.registry import get, make_tracker, names, listing
text = listing()
assert "myplug" not in sys.modules, "naming and listing the trackers imports no plug-in"
print(names())
trk = make_tracker("mine")
print(trk.name, trk.params.search_factor, get("bqp").target)
for bad in ("broken", "misnamed"):
    try:
        get(bad)
    except ValueError as exc:
        print(exc)
print(text)
"""
    run = _python(env, code)
    assert run.returncode == 0, run.stderr
    out = run.stdout.splitlines()
    assert out[0].endswith("'mine', 'broken', 'misnamed')") and out[0].count("'bqp'") == 1
    assert out[1] == "mine 2.5 tracker.bqp.tracker:BQPTracker"  # a plug-in never shadows bqp
    assert out[2].startswith(
        "tracker plug-in 'broken' (myplug_missing:ENTRY, entry point of myplug) does not load: "
        "ModuleNotFoundError"
    )
    assert out[3].endswith("names itself 'other'; the two must agree")
    assert out[4].endswith(
        "; mine: a plug-in of myplug; broken: a plug-in of myplug; misnamed: a plug-in of myplug"
    )


def test_the_cli_tracks_with_a_plugin_and_names_a_broken_one(tmp_path, scene_folder):
    from tracker.testing import make_scene

    sc = make_scene([[20, 20], [90, 20], [100, 75]], [[2, 1], [-2, 1], [-2, 0]], n_frames=6)
    d = scene_folder(sc, tmp_path / "seq")
    env = _plugin_env(tmp_path, "mine = myplug:ENTRY\nbroken = myplug_missing:ENTRY")

    def crowdsim(*args):
        return subprocess.run(
            [sys.executable, "-m", "crowdsim", *args], env=env, capture_output=True, text=True
        )

    run = crowdsim(
        "track",
        str(d),
        "--tracker",
        "mine",
        "--out",
        str(tmp_path / "m.txt"),
        "--evaluate",
        "--no-progress",
    )
    assert run.returncode == 0, run.stderr
    assert (tmp_path / "m.txt").stat().st_size > 0
    run = crowdsim("track", str(d), "--tracker", "broken", "--out", str(tmp_path / "b.txt"))
    assert run.returncode == 2 and not (tmp_path / "b.txt").exists()
    err = run.stderr.strip().splitlines()
    assert len(err) == 1 and "tracker plug-in 'broken'" in err[0] and "does not load" in err[0], err
    run = crowdsim("track", "--help")
    assert run.returncode == 0 and "mine: a plug-in of myplug" in " ".join(run.stdout.split())


REQUIRED = """
from dataclasses import dataclass

from tracker.registry import entry


@dataclass(frozen=True)
class NeedsOne:
    needed: int


ENTRY = entry("req", "tracker.baselines.ncc:NCCTracker", "myplug.req:NeedsOne", "needs a field")
"""


def test_a_plugin_whose_params_do_not_build_is_named_and_breaks_no_other_command(tmp_path):
    """A plug-in whose parameter class has a required field (``TypeError`` when built from its
    defaults) is a plug-in that does not load, named, like one that does not import: the help
    of every command, which lists the trackers, still works."""
    env = _plugin_env(tmp_path, "req = myplug.req:ENTRY")
    (tmp_path / "site" / "myplug" / "req.py").write_text(REQUIRED)
    code = """
from tracker.registry import entries, get, listing
print("req" in entries())
print(listing().split("; ")[-1])
try:
    get("req")
except ValueError as exc:
    print(exc)
"""
    run = _python(env, code)
    assert run.returncode == 0, run.stderr
    out = run.stdout.splitlines()
    assert out[0] == "False"
    assert out[1] == "req: a plug-in of myplug"
    assert out[2].startswith("tracker plug-in 'req' (myplug.req:ENTRY, entry point of myplug)")
    assert "do not build from their defaults: TypeError" in out[2]
    # every command's help lists the trackers: it imports no plug-in, so none can break it
    (tmp_path / "site" / "myplug" / "__init__.py").write_text("raise SystemExit('imported')")
    run = subprocess.run(
        [sys.executable, "-m", "crowdsim", "simulate", "--help"],
        env=env,
        capture_output=True,
        text=True,
    )
    assert run.returncode == 0 and "Traceback" not in run.stderr, run.stderr
