"""Difficulty attribution: one knob group reset at a time, exact spec variants, and a tiny
end-to-end run whose figures come from the table's own cells."""

from __future__ import annotations

import json

import pytest

from crowdsim.cli import main
from crowdsim.lab.calibration import _uncalibrated
from crowdsim.lab.difficulty import DIFFICULTY_GROUPS, attribute, variant_specs
from synth_data.suites import suite_specs


def _knobs(spec):
    d = dict(vars(spec.appearance))
    d.update(spec.camera)
    return d


def test_each_variant_resets_exactly_one_group_to_the_uncalibrated_values():
    (spec,) = suite_specs("ucf9", ["seq9"])
    cal, base = _knobs(spec), _knobs(_uncalibrated(spec))
    variants = dict(variant_specs(spec))
    assert list(variants) == ["calibrated", *[f"-{g}" for g in DIFFICULTY_GROUPS], "uncalibrated"]
    assert _knobs(variants["calibrated"]) == cal and _knobs(variants["uncalibrated"]) == base
    for group, names in DIFFICULTY_GROUPS.items():
        v = variants[f"-{group}"]
        got = _knobs(v)
        for name in cal:
            want = base[name] if name in names else cal[name]
            assert got[name] == want, (group, name)
        assert cal[names[0]] != base[names[0]]  # seq9 is calibrated hard: each group is on
        assert (v.seed, v.scenario, v.frames) == (spec.seed, spec.scenario, spec.frames)
    assert len({v.name for v in variants.values()}) == len(variants)


def test_an_uncalibrated_spec_is_refused():
    (spec,) = suite_specs("ucf9", ["seq9"])
    from dataclasses import replace

    with pytest.raises(ValueError, match="seq9: not calibrated"):
        variant_specs(replace(spec, calibration={}))


def test_attribution_figures_are_the_tables_cells(tmp_path):
    doc = attribute(
        "ucf9", tmp_path, only=["seq9"], trackers=["ncc"], frames=6, progress=False, log=print
    )
    cells = json.loads((tmp_path / "cells.json").read_text())["cells"]
    acc = {k.split("|")[0]: v["acc@15"] for k, v in cells.items()}
    r = doc["sequences"]["seq9"]["ncc"]
    assert r["calibrated"] == acc["seq9.calibrated"] and r["uncalibrated"] == acc["seq9.base"]
    assert r["regained"]["shake"] == pytest.approx(acc["seq9.no-shake"] - acc["seq9.calibrated"])
    text = (tmp_path / "attribution.md").read_text()
    assert "| seq9 | ncc |" in text and "-noise+codec" in text


def test_cli_refuses_an_unknown_tracker(tmp_path, capsys):
    code = main(["difficulty", "--only", "seq9", "--trackers", "nosuch", "--out", str(tmp_path)])
    err = capsys.readouterr().err
    assert code == 2 and "nosuch" in err and "Traceback" not in err
    assert not any(tmp_path.iterdir())  # nothing generated
