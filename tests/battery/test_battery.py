"""Run every case of the bad-input battery (``cases_*.py``); see :mod:`battery.harness`.

Run ``python tests/battery/test_battery.py`` for the counts: tried, clear, traceback, silent
(exit 0 where an error was due), data loss (an input changed or removed) and unclear (an error
that does not name the value, or leaves something behind).
"""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

from battery.harness import Case, Env, _fmt, _umount, build_env, load_cases, names, run_case

CASES = load_cases()


@pytest.fixture(scope="session")
def env(tmp_path_factory):
    e = build_env(tmp_path_factory.mktemp("battery"))
    yield e
    for m in e.mounts:
        _umount(m)


def _params():
    out = []
    for c in CASES:
        marks = [pytest.mark.xfail(strict=True, reason=c.xfail, run=not c.slow)] if c.xfail else []
        out.append(pytest.param(c, id=c.id, marks=marks))
    return out


@pytest.mark.parametrize("c", _params())
def test_bad_input(c: Case, env: Env):
    if c.needs and getattr(env, c.needs) is None:
        pytest.skip(f"cannot mount a {c.needs} tmpfs here (needs root and mount)")
    work = env.root / "cases" / c.id
    outcome = run_case(c, env, work)
    needle = _fmt(c.needle, work, env)
    assert "Traceback" not in outcome.err and outcome.rc is not None, outcome.err
    assert not outcome.lost, f"inputs changed or removed: {outcome.lost}"
    assert outcome.rc == 2, f"exit {outcome.rc}; stderr: {outcome.err!r}"
    assert names(outcome.err, needle), f"{needle!r} not in {outcome.err!r}"
    assert not outcome.new, f"left behind: {outcome.new}"
    lines = [ln for ln in outcome.err.strip().splitlines() if ln.strip()]
    assert len(lines) == 1 or lines[0].startswith("usage:"), outcome.err


def test_battery_is_large_and_unique():
    ids = [c.id for c in CASES]
    assert len(ids) == len(set(ids))
    assert len(CASES) >= 150
    commands = {c.argv[0] for c in CASES if c.argv}
    assert {"simulate", "render", "evaluate", "track", "generate", "demo"} <= commands


if __name__ == "__main__":  # pragma: no cover
    import tempfile

    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # tests/: the battery package
    from battery.harness import summary

    with tempfile.TemporaryDirectory() as d:
        print(summary(Path(d) / "battery", run_slow="--slow" in sys.argv))
