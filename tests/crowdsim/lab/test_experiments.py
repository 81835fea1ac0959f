"""``crowdsim compare`` / ``ablation`` machinery and ``crowdsim calibrate`` on tiny specs."""

from __future__ import annotations

import csv
import io
import json

import pytest

from crowdsim.knobs import apply_knobs, knob_values
from crowdsim.lab import calibration, experiments
from crowdsim.lab.experiments import Row, run_table
from synth_data.spec import load_spec, spec_from_dict


def tiny(name: str = "tiny", frames: int = 8, **appearance):
    return spec_from_dict(
        {
            "name": name,
            "seed": 3,
            "frames": frames,
            "warmup_steps": 2,
            "scenario": {"name": "crossing", "n_agents": 14, "density": 1.0},
            "camera": {"px_per_m": 14.0},
            "appearance": {"template_px": 8, "noise_sigma": 3.0, **appearance},
        },
        source=f"{name}.toml",
    )


ROWS = (Row("NCC", "ncc", paper="NCC"), Row("BQP", "bqp", {"zeta": 0.0}))


def test_table_cells_files_and_resume(tmp_path, monkeypatch):
    out = tmp_path / "t"
    text = run_table(ROWS, [tiny("a"), tiny("b")], out, progress=False, log=lambda m: None)
    assert "## acc@15" in text and "| NCC |" in text and "| BQP |" in text
    rows = list(csv.DictReader(io.StringIO((out / "table.csv").read_text())))
    assert [(r["method"], r["sequence"]) for r in rows] == [
        ("NCC", "a"),
        ("NCC", "b"),
        ("BQP", "a"),
        ("BQP", "b"),
    ]
    for r in rows:
        assert 0.0 <= float(r["acc@15"]) <= 100.0 and float(r["fps"]) > 0
    assert (out / "curves" / "a.png").stat().st_size > 0
    cells = json.loads((out / "cells.json").read_text())["cells"]
    assert len(cells) == 4
    # a rerun resumes: no cell is tracked again, and the table is the same
    monkeypatch.setattr(experiments, "run_cell", lambda *a: pytest.fail("cell rerun"))
    again = run_table(ROWS, [tiny("a"), tiny("b")], out, progress=False, log=lambda m: None)
    assert again == text


def test_bad_rows_fail_before_any_work(tmp_path):
    with pytest.raises(ValueError, match="no parameter"):
        run_table((Row("x", "bqp", {"zetaa": 1.0}),), [tiny()], tmp_path / "t", progress=False)
    with pytest.raises(ValueError, match="valid trackers"):
        run_table((Row("x", "kalman"),), [tiny()], tmp_path / "t", progress=False)
    assert not (tmp_path / "t").exists()


def test_paper_figures_sit_beside_ours():
    paper = experiments.paper_numbers("ucf9")
    assert paper["acc@15"]["NCC"]["seq5"] == 33 and paper["acc@5"]["BQP"]["seq1"] == 72.8
    cells = {
        ("seq5", "NCC"): {
            "acc@15": 31.25,
            "acc@5": 20.0,
            "mota": 1.0,
            "idf1": 2.0,
            "hota": 3.0,
            "fps": 9.0,
        }
    }
    text = experiments.format_table((Row("NCC", "ncc", paper="NCC"),), ["seq5"], cells, paper)
    assert "| NCC | 31.2% (33) | 31.2% |" in text
    assert len(experiments.ablation_rows()) == 12
    assert {r.label for r in experiments.ablation_rows()} <= set(paper["ablation@15"])


def test_difficulty_makes_ncc_worse_and_calibration_lands_on_the_target(tmp_path):
    spec = spec_from_dict(
        {
            "name": "m",
            "seed": 3,
            "frames": 30,
            "warmup_steps": 2,
            "scenario": {"name": "marathon", "n_agents": 60, "density": 2.5},
            "camera": {"max_width": 320, "max_height": 240},
            "appearance": {"template_px": 8, "noise_sigma": 3.0},
        },
        source="m.toml",
    )
    easy = calibration.ncc_score(spec, tmp_path / "w")
    hard = calibration.ncc_score(apply_knobs(spec, knob_values(spec, 1.0, 1.0)), tmp_path / "w")
    assert hard < easy - 20
    target = (easy + hard) / 2
    res = calibration.calibrate_spec(
        spec, target, trials=6, storage=f"sqlite:///{tmp_path / 'c.db'}", log=lambda m: None
    )
    assert res["error"] < min(easy - target, target - hard)
    assert 0 < res["difficulty"] < 1 and res["trials"] <= 6
    # resumable: the same study continues and does not start again
    again = calibration.calibrate_spec(
        spec,
        target,
        trials=6,
        storage=f"sqlite:///{tmp_path / 'c.db'}",
        log=lambda m: pytest.fail("a trial ran again"),
    )
    assert again["difficulty"] == res["difficulty"]


SPEC_TEXT = """# a hand-written spec: comments and layout must survive calibration
name = "lobby"
seed = 8
frames = 12

[scenario]
name = "station"  # people leave through doors
n_agents = 20

[camera]
max_width = 320

[appearance]
template_px = 10
noise_sigma = 4.0  # sensor

[calibration]
paper_ncc_15px = 86.0
"""


def test_write_calibration_keeps_the_file_and_records_the_base(tmp_path):
    path = tmp_path / "lobby.toml"
    path.write_text(SPEC_TEXT)
    before = load_spec(path)
    values = knob_values(before, 0.4, 0.4)
    calibration.write_calibration(
        path, {"difficulty": 0.4, "ncc_15px": 85.5, "trials": 5, "values": values}
    )
    text = path.read_text()
    assert text.startswith("# a hand-written spec") and "# people leave through doors" in text
    assert "noise_sigma = " in text and "# sensor" in text  # replaced in place, comment kept
    after = load_spec(path)
    for (section, name), v in values.items():
        got = getattr(after.appearance, name) if section == "appearance" else after.camera[name]
        assert got == pytest.approx(v)
    assert after.calibration["achieved_ncc_15px"] == 85.5
    assert after.calibration["paper_ncc_15px"] == 86.0
    assert after.scenario == before.scenario and after.seed == before.seed  # motion untouched
    # the values before the first calibration are recorded once and restore the knobs
    calibration.write_calibration(
        path,
        {
            "difficulty": 0.9,
            "ncc_15px": 40.0,
            "trials": 2,
            "values": knob_values(after, 0.9, 0.9),
        },
    )
    restored = calibration._uncalibrated(load_spec(path))
    assert restored.appearance == before.appearance
    assert restored.camera.get("jitter_px", 0.0) == before.camera.get("jitter_px", 0.0)


def test_knob_values_are_validated():
    with pytest.raises(ValueError, match="difficulty|scene"):
        knob_values(tiny(), 1.5, 0.0)
    vals = knob_values(tiny(), 0.0, 0.0)
    assert vals[("appearance", "video_kbps")] == 0.0  # d = 0 is the spec as written
    assert vals[("appearance", "noise_sigma")] == 3.0
