"""``crowdsim compare`` / ``ablation`` machinery and ``crowdsim calibrate`` on tiny specs."""

from __future__ import annotations

import contextlib
import csv
import io
import json
import shutil

import pytest

from crowdsim.knobs import apply_knobs, knob_values
from crowdsim.lab import calibration, experiments
from crowdsim.lab.experiments import Row, run_table
from synth_data.detections import DetectionParams
from synth_data.spec import load_spec, spec_from_dict
from tracker.detect.inference import DetectorParams


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


def test_cells_resumed_from_other_code_are_named_in_the_table(tmp_path, monkeypatch):
    """A cell holds the digest of the code that measured it; a rerun with other code (another
    release) still resumes it, but the table says how many of its cells came from that code."""
    out = tmp_path / "t"
    quiet = {"progress": False, "log": lambda m: None}
    text = run_table(ROWS, [tiny("a")], out, **quiet)
    cells = json.loads((out / "cells.json").read_text())["cells"]
    assert {c[experiments.CODE] for c in cells.values()} == {experiments.code_digest()}
    assert "Note:" not in text
    monkeypatch.setattr(experiments, "code_digest", lambda: "0123456789ab")
    monkeypatch.setattr(experiments, "run_cell", lambda *a: pytest.fail("cell rerun"))
    again = run_table(ROWS, [tiny("a")], out, **quiet)
    note = (
        "Note: 2 of 2 cells were measured by an earlier run with other tracker code than "
        "this run's (0123456789ab), and resumed from cells.json"
    )
    assert again.startswith(text) and note in again
    assert note in (out / "table.md").read_text()


def test_the_code_digest_changes_with_any_python_file_of_the_packages(tmp_path, monkeypatch):
    """Every Python file, by path and content, and nothing else (compiled files)."""
    pkg = tmp_path / "codepkg"
    (pkg / "sub").mkdir(parents=True)
    (pkg / "__init__.py").write_text("")
    (pkg / "sub" / "mod.py").write_text("X = 1\n")
    monkeypatch.setattr(experiments, "code_roots", lambda: {"codepkg": pkg})

    def digest():
        experiments.code_digest.cache_clear()
        return experiments.code_digest()

    try:
        first = digest()
        assert len(first) == 12 and digest() == first
        (pkg / "sub" / "__pycache__").mkdir()
        (pkg / "sub" / "__pycache__" / "mod.cpython-311.pyc").write_bytes(b"\0")
        assert digest() == first
        (pkg / "sub" / "mod.py").write_text("X = 2\n")
        edited = digest()
        assert edited != first
        (pkg / "sub" / "mod.py").rename(pkg / "sub" / "other.py")
        assert digest() not in (first, edited)
    finally:
        experiments.code_digest.cache_clear()


def test_frames_at_or_past_a_sequences_length_resume_the_whole_sequences_cells(
    tmp_path, monkeypatch
):
    """``--frames`` that cuts nothing is the same work as none: the cells are found again
    (they were keyed ``frames=N`` and rerun); a cut is still its own cell."""
    out = tmp_path / "t"
    quiet = {"progress": False, "log": lambda m: None}
    run_table(ROWS, [tiny("a")], out, **quiet)
    monkeypatch.setattr(experiments, "run_cell", lambda *a: pytest.fail("cell rerun"))
    for frames in (8, 50):
        text = run_table(ROWS, [tiny("a")], out, frames=frames, **quiet)
        assert f"first {frames} frames" in text  # the title still says what was asked
    keys = json.loads((out / "cells.json").read_text())["cells"]
    assert [k.rsplit("|", 1)[1] for k in keys] == ["frames=all"] * 2
    assert experiments.key_frames(7, tiny("a")) == 7  # a cut: its own cells
    assert experiments.key_frames(None, tiny("a")) is None


def test_bad_rows_fail_before_any_work(tmp_path):
    with pytest.raises(ValueError, match="no parameter"):
        run_table((Row("x", "bqp", {"zetaa": 1.0}),), [tiny()], tmp_path / "t", progress=False)
    with pytest.raises(ValueError, match="valid trackers"):
        run_table((Row("x", "kalman"),), [tiny()], tmp_path / "t", progress=False)
    with pytest.raises(ValueError, match="row 'x' gives a detector, but tracker 'ncc' takes no"):
        run_table(
            (Row("x", "ncc", detections=DetectionParams()),),
            [tiny()],
            tmp_path / "t",
            progress=False,
        )
    with pytest.raises(ValueError, match="tracker 'bytetrack' has no parameter\\(s\\) miss_rate"):
        run_table(
            (Row("x", "bytetrack", {"miss_rate": 0.3}),), [tiny()], tmp_path / "t", progress=False
        )
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
    assert "The NCC and MS figures in brackets are [11]'s implementations" in text
    b = experiments.ablation_rows()[:1]
    ablation = experiments.format_table(
        b, ["seq5"], {("seq5", b[0].label): cells[("seq5", "NCC")]}, paper
    )
    assert "[11]" not in ablation  # paper 1's own rows are not labelled as [11]'s
    assert "Figures in brackets: the papers'" in text
    # a suite without paper.json (stress, galleria): no brackets, and no note promising them
    none = experiments.format_table((Row("NCC", "ncc", paper="NCC"),), ["seq5"], cells, {})
    assert "Figures in brackets" not in none and "(33)" not in none
    assert none.rstrip().endswith("the papers report none for these sequences.")
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
    easy = calibration.score(spec, tmp_path / "w", "ncc11")
    hard = calibration.score(
        apply_knobs(spec, knob_values(spec, 1.0, 1.0)), tmp_path / "w", "ncc11"
    )
    assert hard < easy - 20
    target = (easy + hard) / 2
    res = calibration.calibrate_spec(
        spec,
        target,
        anchor="ncc11",
        trials=6,
        storage=f"sqlite:///{tmp_path / 'c.db'}",
        log=lambda m: None,
    )
    assert res["error"] < min(easy - target, target - hard)
    assert 0 < res["difficulty"] < 1 and res["trials"] <= 6
    # resumable: the same study continues and does not start again
    again = calibration.calibrate_spec(
        spec,
        target,
        anchor="ncc11",
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
        path,
        {"anchor": "ncc11", "difficulty": 0.4, "score_15px": 85.5, "trials": 5, "values": values},
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
            "anchor": "ncc11",
            "score_15px": 40.0,
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


# ------------------------------------------------------------------ the tables map cells right
def test_a_sequence_of_another_suite_or_an_edited_spec_is_another_cell():
    """The key holds the digest of what the spec renders: another suite's seq8 of the same
    name had reused the first suite's cells (and shown them under the second's title)."""
    from synth_data.suites import suite_specs

    row = experiments.COMPARE_ROWS[0]
    (still,) = suite_specs("ucf9", ["seq8"])
    (shaken,) = suite_specs("ucf9-shake", ["seq8"])
    assert still.name == shaken.name
    assert experiments.cell_key(still, row, 30) != experiments.cell_key(shaken, row, 30)
    assert experiments.cell_key(still, row, 30) == experiments.cell_key(still, row, 30)


def test_every_row_has_its_own_cell_key():
    for rows in (experiments.COMPARE_ROWS, experiments.ablation_rows()):
        for frames in (None, 40):
            keys = [experiments.cell_key("seq5", r, frames) for r in rows]
            assert len(set(keys)) == len(keys)
            assert all(k.startswith("seq5|") for k in keys)
    # another sequence or frame count never reuses a cell
    row = experiments.COMPARE_ROWS[5]  # ByteTrack miss 0.1
    assert row.overrides == {} and row.detections == DetectionParams(miss_rate=0.1)
    assert len({experiments.cell_key(s, row, f) for s in ("seq1", "seq2") for f in (None, 9)}) == 4
    # the detector is part of the key: another detector is another cell; no detector is the
    # default one (the detector a detection tracker then gets)
    other = Row(row.label, row.tracker, detections=DetectionParams(miss_rate=0.1, seed=1))
    default = Row(row.label, row.tracker)
    assert experiments.cell_key("s", other, None) != experiments.cell_key("s", row, None)
    assert experiments.cell_key("s", default, None) == experiments.cell_key(
        "s", Row("y", "bytetrack", detections=DetectionParams()), None
    )


def _differing_specs():
    """Two tiny sequences that really differ: other seeds, crowds and noise."""
    a = tiny("a", frames=8)
    b = spec_from_dict(
        {
            "name": "b",
            "seed": 11,
            "frames": 8,
            "warmup_steps": 2,
            "scenario": {"name": "marathon", "n_agents": 30, "density": 2.5},
            "camera": {"px_per_m": 14.0},
            "appearance": {"template_px": 8, "noise_sigma": 20.0, "contrast": 0.3},
        },
        source="b.toml",
    )
    return [a, b]


def test_cells_are_read_back_per_sequence_and_method(tmp_path):
    out = tmp_path / "t"
    rows = (Row("NCC", "ncc", paper="NCC"), Row("mean-shift", "meanshift", paper="MS"))
    specs = _differing_specs()
    run_table(rows, specs, out, progress=False, log=lambda m: None)
    cells = json.loads((out / "cells.json").read_text())["cells"]
    by = {
        (sp.name, row.label): cells[experiments.cell_key(sp, row, None)]
        for sp in specs
        for row in rows
    }
    figures = {k: (c["acc@15"], c["mota"], c["hota"]) for k, c in by.items()}
    assert len(set(figures.values())) == 4, figures  # every cell measures something else
    got = {
        (r["sequence"], r["method"]): r
        for r in csv.DictReader(io.StringIO((out / "table.csv").read_text()))
    }
    assert set(got) == set(by)
    for key, cell in by.items():
        for metric in ("acc@15", "acc@5", "mota", "idf1", "hota"):
            assert float(got[key][metric]) == pytest.approx(cell[metric], abs=5e-4), key
    md = (out / "table.md").read_text()
    section = md.split("## acc@15")[1].split("##")[0]
    for row in rows:
        line = next(ln for ln in section.splitlines() if ln.startswith(f"| {row.label} |"))
        assert line.split(" | ")[1:3] == [f"{by[(s, row.label)]['acc@15']:.1f}%" for s in "ab"]


def test_paper_columns_come_from_the_right_table():
    paper = experiments.paper_numbers("ucf9")
    want = json.loads((experiments_paper_file()).read_text())
    seqs = [f"seq{i}" for i in range(1, 10)]
    cell = {"acc@15": 50.0, "acc@5": 40.0, "mota": 1.0, "idf1": 2.0, "hota": 3.0, "fps": 9.0}
    for rows, table in (
        (experiments.COMPARE_ROWS, "acc@15"),
        (experiments.ablation_rows(), "ablation@15"),
    ):
        cells = {(s, r.label): cell for s in seqs for r in rows}
        got = list(
            csv.DictReader(io.StringIO(experiments.table_csv(rows, seqs, cells, paper, table)))
        )
        text = experiments.format_table(rows, seqs, cells, paper, table)
        section = text.split("## acc@15")[1].split("##")[0]
        for r in rows:
            line = next(ln for ln in section.splitlines() if ln.startswith(f"| {r.label} |"))
            for s, shown in zip(seqs, line.split(" | ")[1:10], strict=True):
                ref = want[table].get(r.paper, {}).get(s) if r.paper else None
                assert shown == ("50.0%" if ref is None else f"50.0% ({ref:g})"), (r.label, s)
                row = next(x for x in got if x["method"] == r.label and x["sequence"] == s)
                assert row["paper_acc@15"] == ("" if ref is None else str(ref))
                p5 = want["acc@5"].get(r.paper, {}).get(s) if r.paper else None
                assert row["paper_acc@5"] == ("" if p5 is None else str(p5))
    # the columns really differ: a mix-up of two would show
    assert paper["acc@15"]["MS"]["seq2"] == 67 and paper["acc@15"]["PNMC"]["seq2"] == 100
    assert paper["ablation@15"]["B (NCC)"]["seq1"] == 78.13


def experiments_paper_file():
    from synth_data.suites import suite_dir

    return suite_dir("ucf9") / "paper.json"


# ------------------------------------------------------------------ checked cells and flags
def _fake_cell(seq_dir, tracker, overrides, frames, detections=None):
    from pathlib import Path

    v = float(sum(map(ord, Path(seq_dir).name + tracker)) % 90)
    return {k: v for k in ("acc@15", "acc@5", "mota", "idf1", "hota", "fps")} | {"curve": []}


def test_a_hand_edited_cell_is_refused_naming_it(tmp_path, monkeypatch):
    monkeypatch.setattr(experiments, "run_cell", _fake_cell)
    out = tmp_path / "t"
    text = run_table(ROWS, [tiny("a")], out, progress=False, log=lambda m: None)
    assert f"| NCC | {_fake_cell('a', 'ncc', {}, None)['acc@15']:.1f}% |" in text
    assert f"| BQP | {_fake_cell('a', 'bqp', {}, None)['acc@15']:.1f}% |" in text
    path = out / "cells.json"
    original = path.read_bytes()
    data = json.loads(original)
    key = experiments.cell_key(tiny("a"), ROWS[0], None)
    data["cells"][key]["acc@15"] = 999.0
    path.write_text(json.dumps(data))
    before = path.read_bytes()
    with pytest.raises(
        ValueError, match=r"cells.json: cell 'a@[0-9a-f]{12}\|ncc\|.*does not match its checksum"
    ):
        run_table(ROWS, [tiny("a")], out, progress=False, log=lambda m: None)
    assert path.read_bytes() == before
    # a cell moved under another key fails as well
    data = json.loads(original)
    other = experiments.cell_key(tiny("a"), ROWS[1], None)
    data["cells"][key], data["cells"][other] = data["cells"][other], data["cells"][key]
    path.write_text(json.dumps(data))
    with pytest.raises(ValueError, match="does not match its checksum"):
        experiments.read_cells(path)
    data = json.loads(original)  # sealed as the checksum wants, but no figure in it
    data["cells"][key] = experiments.seal_cell(key, {**data["cells"][key], "acc@15": "n/a"})
    path.write_text(json.dumps(data))
    with pytest.raises(ValueError, match=r"cells.json: cell 'a@.*' holds acc@15 = 'n/a', not a"):
        run_table(ROWS, [tiny("a")], out, progress=False, log=lambda m: None)
    for bad, needle in (
        (b"\x00\xff binary", "damaged"),
        (b"[1, 2]", "no 'cells' object"),
        (b'{"format": 2, "cells": {}}', "a cells file of format 2, not crowdsim's 1"),
    ):
        path.write_bytes(bad)
        (out / experiments.OUTPUTS_FILE).unlink(missing_ok=True)
        with pytest.raises(ValueError, match=needle):  # before any work: nothing is written
            run_table(ROWS, [tiny("a")], out, progress=False, log=lambda m: None)
        assert path.read_bytes() == bad and not (out / experiments.OUTPUTS_FILE).exists()


def test_a_rerun_replaces_its_own_tables_and_never_a_users_file(tmp_path, monkeypatch):
    monkeypatch.setattr(experiments, "run_cell", _fake_cell)
    out = tmp_path / "t"
    first = run_table(ROWS, [tiny("a")], out, progress=False, log=lambda m: None)
    record = json.loads((out / experiments.OUTPUTS_FILE).read_text())
    assert set(record["files"]) == {"table.md", "table.csv"}
    assert run_table(ROWS, [tiny("a")], out, progress=False, log=lambda m: None) == first
    (out / "table.md").write_text("my notes\n")
    with pytest.raises(ValueError, match=r"--out: .*table.md exists and was not written by a "):
        run_table(ROWS, [tiny("a")], out, progress=False, log=lambda m: None)
    assert (out / "table.md").read_text() == "my notes\n"
    # a user's folder: refused before anything is generated or run
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "table.csv").write_text("my,table\n")
    with pytest.raises(ValueError, match=r"table.csv exists and was not written by a "):
        run_table(ROWS, [tiny("a")], mine, progress=False, log=lambda m: None)
    assert sorted(p.name for p in mine.iterdir()) == ["table.csv"]
    # a folder from before the record: its cells vouch for the tables beside them
    (out / experiments.OUTPUTS_FILE).unlink()
    assert run_table(ROWS, [tiny("a")], out, progress=False, log=lambda m: None) == first
    assert (out / "table.md").read_text() == first


def test_a_run_stopped_before_its_record_does_not_look_like_a_folder_from_before_it(
    tmp_path, monkeypatch
):
    """A run stopped (Ctrl-C, a kill, a full disk) after its cells but before its tables
    leaves a record listing nothing: a user's table.md put there afterwards is refused, not
    replaced as if a release from before the record had written it."""
    import envs.outputs

    monkeypatch.setattr(experiments, "run_cell", _fake_cell)
    out, quiet = tmp_path / "t", {"progress": False, "log": lambda m: None}

    def stopped(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(envs.outputs, "write_outputs", stopped)
    with pytest.raises(KeyboardInterrupt):
        run_table(ROWS, [tiny("a")], out, **quiet)
    assert (out / experiments.CELLS_FILE).is_file()
    assert json.loads((out / experiments.OUTPUTS_FILE).read_text())["files"] == {}
    monkeypatch.undo()
    monkeypatch.setattr(experiments, "run_cell", _fake_cell)
    (out / "table.md").write_text("my notes\n")
    with pytest.raises(ValueError, match=r"table.md exists and was not written by a "):
        run_table(ROWS, [tiny("a")], out, **quiet)
    assert (out / "table.md").read_text() == "my notes\n"


def test_a_run_over_fewer_sequences_keeps_vouching_for_the_others_curves(tmp_path, monkeypatch):
    def cell(seq_dir, tracker, overrides, frames, detections=None):
        return _fake_cell(seq_dir, tracker, overrides, frames) | {"curve": [50.0] * 26}

    monkeypatch.setattr(experiments, "run_cell", cell)
    out, quiet = tmp_path / "t", {"progress": False, "log": lambda m: None}
    run_table(ROWS, [tiny("a"), tiny("b")], out, **quiet)
    run_table(ROWS, [tiny("a")], out, **quiet)  # rewrites a's curve, leaves b's
    files = json.loads((out / experiments.OUTPUTS_FILE).read_text())["files"]
    assert {"curves/a.png", "curves/b.png"} <= set(files)
    run_table(ROWS, [tiny("a"), tiny("b")], out, **quiet)  # b's curve is still provably ours
    (out / "curves" / "b.png").write_bytes(b"my own plot")
    with pytest.raises(ValueError, match=r"b.png exists and was not written by a "):
        run_table(ROWS, [tiny("a"), tiny("b")], out, **quiet)


def test_address_needs_ray_and_a_suite_folder_brings_its_paper_figures(tmp_path, monkeypatch):
    with pytest.raises(ValueError, match="--address needs --backend ray, got --address 'x:1'"):
        run_table(ROWS, [tiny("a")], tmp_path / "t", address="x:1", progress=False)
    assert not (tmp_path / "t").exists()
    suite = tmp_path / "suite"
    suite.mkdir()
    (suite / "a.toml").write_text(
        'name = "a"\nseed = 3\nframes = 6\n[scenario]\nname = "crossing"\nn_agents = 8\n'
        "[camera]\npx_per_m = 14.0\n[appearance]\ntemplate_px = 8\n"
    )
    (suite / "paper.json").write_text('{"acc@15": {"NCC": {"a": 42.5}}}')
    monkeypatch.setattr(experiments, "run_cell", _fake_cell)
    text = run_table(ROWS, suite, tmp_path / "t", progress=False, log=lambda m: None)
    assert f"| NCC | {_fake_cell('a', 'ncc', {}, None)['acc@15']:.1f}% (42.5) |" in text
    (suite / "paper.json").write_text('{"acc@15": {"NCC": {"a": "high"}}}')
    with pytest.raises(ValueError, match=r"paper.json: acc@15.NCC.a must be a percentage"):
        run_table(ROWS, suite, tmp_path / "t", progress=False, log=lambda m: None)


def test_compare_rows_feed_their_detector_to_the_cell(tmp_path, monkeypatch):
    seen = {}

    def record(seq_dir, tracker, overrides, frames, detections=None):
        seen[(tracker, detections)] = overrides
        return _fake_cell(seq_dir, tracker, overrides, frames)

    rows = tuple(r for r in experiments.COMPARE_ROWS if r.tracker in ("bytetrack", "ocsort"))
    assert [r.label for r in rows] == [
        "ByteTrack miss 0.1",
        "ByteTrack miss 0.3",
        "OC-SORT miss 0.1",
        "OC-SORT miss 0.3",
        "ByteTrack (head detector)",
        "OC-SORT (head detector)",
    ]
    monkeypatch.setattr(experiments, "run_cell", record)
    run_table(rows, [tiny("a")], tmp_path / "t", progress=False, log=lambda m: None)
    simulated = {
        (t, DetectionParams(miss_rate=m)): {} for t in ("bytetrack", "ocsort") for m in (0.1, 0.3)
    }
    trained = {(t, DetectorParams()): {} for t in ("bytetrack", "ocsort")}
    assert seen == simulated | trained
    assert all(r.detections is None for r in experiments.COMPARE_ROWS if r not in rows)


def test_a_detection_row_tracks_with_its_own_detector(tmp_path):
    pytest.importorskip("trackers", reason="needs the optional 'trackers' package ([detect])")
    clean = DetectionParams(miss_rate=0.0, false_alarm_rate=0.0, jitter_px=0.0)
    rows = (
        Row("clean", "bytetrack", detections=clean),
        Row("poor", "bytetrack", detections=DetectionParams(miss_rate=0.9)),
    )
    out = tmp_path / "t"
    run_table(rows, [tiny("a", frames=10)], out, progress=False, log=lambda m: None)
    cells = experiments.read_cells(out / experiments.CELLS_FILE)
    acc = {
        r.label: cells[experiments.cell_key(tiny("a", frames=10), r, None)]["acc@15"] for r in rows
    }
    assert acc["clean"] > 80.0 and acc["poor"] < 20.0


def test_a_row_fed_by_the_trained_detector_finds_the_people(tmp_path):
    pytest.importorskip("trackers", reason="needs the optional 'trackers' package ([detect])")
    pytest.importorskip("torch", reason="needs torch ([detect])")
    rows = (Row("detector", "bytetrack", detections=DetectorParams()),)
    out = tmp_path / "t"
    run_table(rows, [tiny("a", frames=10)], out, progress=False, log=lambda m: None)
    cells = experiments.read_cells(out / experiments.CELLS_FILE)
    assert cells[experiments.cell_key(tiny("a", frames=10), rows[0], None)]["acc@15"] > 70.0


def test_new_weights_are_a_new_cell(tmp_path):
    import shutil

    from tracker.detect.inference import DEFAULT_WEIGHTS

    other = tmp_path / "other.pt"
    shutil.copy(DEFAULT_WEIGHTS, other)
    with open(other, "ab") as fh:
        fh.write(b"\0")
    a = experiments.cell_key("a", Row("x", "bytetrack", detections=DetectorParams()), None)
    b = Row("x", "bytetrack", detections=DetectorParams(weights=str(other)))
    assert a != experiments.cell_key("a", b, None)


def test_with_cmc_adds_a_compensated_row_for_each_detection_free_tracker():
    from crowdsim.lab.experiments import COMPARE_ROWS, with_cmc

    rows = with_cmc(COMPARE_ROWS)
    added = [r for r in rows if r not in COMPARE_ROWS]
    assert [r.tracker for r in added] == ["ncc", "meanshift", "pnmc", "bqp", "bqp-ncc"]
    assert all(r.overrides == {"cmc": True} and r.label.endswith(" + CMC") for r in added)
    assert rows[rows.index(COMPARE_ROWS[0]) + 1] == added[0]  # each beside its own row


def test_with_params_sets_a_parameter_on_the_rows_whose_tracker_has_it():
    """compare/ablation --set: the rows whose tracker has the field get it, the others stay
    as they were; a field no row has, or one a row sets itself, is refused by name."""
    from crowdsim.lab.experiments import COMPARE_ROWS, ablation_rows, with_cmc, with_params

    rows = with_params(COMPARE_ROWS, {"fw_variant": "block", "fw_eps": 0.02})
    for old, new in zip(COMPARE_ROWS, rows, strict=True):
        if old.tracker in ("bqp", "bqp-ncc"):
            assert new.overrides == {**old.overrides, "fw_variant": "block", "fw_eps": 0.02}
        else:
            assert new == old
    assert experiments.cell_key("s", rows[3], None) != experiments.cell_key(
        "s", COMPARE_ROWS[3], None
    )  # never resumed from a cell run without the setting
    assert with_params(COMPARE_ROWS, {}) == tuple(COMPARE_ROWS)
    with pytest.raises(ValueError, match="--set nosuch: no row's tracker has that parameter"):
        with_params(COMPARE_ROWS, {"nosuch": 1})
    with pytest.raises(ValueError, match="--set zeta: row 'B .NCC.' sets zeta itself"):
        with_params(ablation_rows(), {"zeta": 0.5})
    with pytest.raises(ValueError, match="--set cmc: row 'NCC [+] CMC' sets cmc itself"):
        with_params(with_cmc(COMPARE_ROWS), {"cmc": True})


def test_compare_trackers_and_cmc_run_only_those_rows(tmp_path, capsys):
    from crowdsim.cli import main

    suite = tmp_path / "suite"
    suite.mkdir()
    (suite / "a.toml").write_text(
        'name = "a"\nseed = 3\nframes = 5\nwarmup_steps = 2\n'
        '[scenario]\nname = "crossing"\nn_agents = 14\ndensity = 1.0\n'
        "[camera]\npx_per_m = 14.0\njitter_px = 1.0\n[appearance]\ntemplate_px = 8\n"
    )
    out = tmp_path / "cmp"
    argv = ["compare", "--suite", str(suite), "--trackers", "ncc", "--cmc", "--no-progress"]
    assert main([*argv, "--out", str(out)]) == 0
    rows = {line.split("|")[1].strip() for line in (out / "table.md").read_text().splitlines()
            if line.startswith("| ") and not line.startswith("| method")}  # fmt: skip
    assert rows == {"NCC", "NCC + CMC"}
    cells = json.loads((out / "cells.json").read_text())["cells"]
    assert len(cells) == 2
    # --set: the same rows with the setting, new cells, the title names it
    assert main([*argv, "--set", "search_factor=1.5", "--out", str(out)]) == 0
    assert (out / "table.md").read_text().startswith("# compare on ")
    assert "with search_factor=1.5" in (out / "table.md").read_text().splitlines()[0]
    assert len(json.loads((out / "cells.json").read_text())["cells"]) == 4
    # a registered tracker without a row of its own gets one under its name
    argv = ["compare", "--suite", str(suite), "--trackers", "bqp-dense", "--no-progress"]
    assert main([*argv, "--out", str(tmp_path / "dense")]) == 0
    table = (tmp_path / "dense" / "table.md").read_text()
    assert "| bqp-dense |" in table
    # --params: a row per tuned parameter file, its own cell; --set of its field is refused
    tuned = tmp_path / "t1" / "best_params.json"
    tuned.parent.mkdir()
    tuned.write_text('{"tracker": "ncc", "params": {"update_threshold": 0.7}}')
    argv = ["compare", "--suite", str(suite), "--trackers", "ncc", "--params", str(tuned)]
    assert main([*argv, "--no-progress", "--out", str(tmp_path / "tuned")]) == 0
    label = f"ncc tuned ({tuned.as_posix()})"
    assert f"| {label} |" in (tmp_path / "tuned" / "table.md").read_text()
    assert len(json.loads((tmp_path / "tuned" / "cells.json").read_text())["cells"]) == 2
    capsys.readouterr()
    bad = [*argv, "--set", "update_threshold=0.5", "--out", str(tmp_path / "t2")]
    assert main(bad) == 2
    assert f"row {label!r} sets update_threshold" in capsys.readouterr().err


def test_a_trackers_first_cell_is_timed_after_its_kernels_compile(tmp_path, monkeypatch):
    """The first cell of a tracker in a process runs a few untimed frames first (a fresh
    clone's first BQP cell had read 1.0 frames/s, the compilation's 33 s); later cells don't."""
    import tracker.runner as runner
    from synth_data.generate import generate

    generate([tiny("w")], tmp_path / "s", progress=False, log=lambda m: None)
    calls = []
    real = runner.run_tracker
    monkeypatch.setattr(
        runner, "run_tracker", lambda *a, **k: calls.append(k.get("frames")) or real(*a, **k)
    )
    monkeypatch.setattr(experiments, "_WARMED", set())
    seq = str(tmp_path / "s" / "w")
    first = experiments.run_cell(seq, "ncc", {}, None)
    assert calls == [3, None]  # the warm-up, then the timed cell
    second = experiments.run_cell(seq, "ncc", {}, None)
    assert calls == [3, None, None] and first["acc@15"] == second["acc@15"]
    experiments.run_cell(seq, "ncc", {"search_factor": 1.5}, None)  # other kernels' types
    assert calls[3:] == [3, None]


# ---------------------------------------------------------------- compare --sequences
@pytest.fixture(scope="module")
def generated(tmp_path_factory):
    """A folder of one tiny sequence (10 frames) as ``crowdsim generate`` writes it."""
    from crowdsim.cli import main

    spec = tmp_path_factory.mktemp("spec") / "a.toml"
    spec.write_text(
        'name = "a"\nseed = 3\nframes = 10\nwarmup_steps = 2\n'
        '[scenario]\nname = "crossing"\nn_agents = 14\ndensity = 1.0\n'
        "[camera]\npx_per_m = 14.0\n[appearance]\ntemplate_px = 8\n"
    )
    seqs = tmp_path_factory.mktemp("generated") / "seqs"
    argv = ["generate", "--spec", str(spec), "--frames", "10", "--workers", "1"]
    assert main([*argv, "--no-progress", "--out", str(seqs)]) == 0
    return seqs


def _user_folder(generated, tmp_path):
    """``tmp_path/mine``: the generated sequence ``a`` and a copy ``b`` without its
    ``checksums.json`` (as MOTChallenge footage comes)."""
    mine = tmp_path / "mine"
    shutil.copytree(generated / "a", mine / "a")
    shutil.copytree(generated / "a", mine / "b")
    (mine / "b" / "checksums.json").unlink()
    return mine


def _snapshot(folder):
    from crowdsim.atomic import sha256_file

    return {
        str(p): (p.stat().st_mtime_ns, sha256_file(p)) for p in sorted(folder.rglob("*"))
        if p.is_file()
    }  # fmt: skip


def test_generates_hidden_folders_are_not_sequences_of_a_folder(generated, tmp_path):
    """A ``generate`` writing into (or killed in) a folder leaves its sequence half-made in a
    hidden ``.crowdsim-tmp-*`` folder, and an ``--overwrite`` the old one renamed aside in a
    ``.crowdsim-old-*``: neither is a sequence of the folder (they had been tracked as
    sequences of their own, beside the one they are a copy of)."""
    from synth_data.writer import OLD_PREFIX, TMP_PREFIX

    mine = _user_folder(generated, tmp_path)
    shutil.copytree(generated / "a", mine / f"{TMP_PREFIX}c-123-0123abcd")
    shutil.copytree(generated / "a", mine / f"{OLD_PREFIX}a-123-0123abcd")
    got = experiments.user_sequences(mine, None, 8, tmp_path / "cmp", log=lambda m: None)
    assert [s.name for s in got] == ["a", "b"]


def test_compare_runs_every_row_on_a_folder_of_mot_sequences(generated, tmp_path, monkeypatch):
    """``compare --sequences``: a row per tracker with figures on each sequence, the papers'
    absence said, the user's folder untouched; a rerun resumes; an edited gt.txt is a new
    cell of that sequence only."""
    from crowdsim.cli import main

    mine = _user_folder(generated, tmp_path)
    before = _snapshot(mine)
    out = tmp_path / "cmp"
    argv = ["compare", "--sequences", str(mine), "--trackers", "ncc", "ocsort", "--frames", "8"]
    argv += ["--no-progress", "--out", str(out)]
    assert main(argv) == 0
    table = (out / "table.md").read_text()
    assert table.startswith(f"# compare on {mine}, first 8 frames of each sequence")
    assert "No figures in brackets: these are your own sequences" in table
    ncc = next(ln for ln in table.splitlines() if ln.startswith("| NCC |"))
    assert "(" not in ncc  # a paper's row, with no papers' figure beside it
    labels = ["NCC", "OC-SORT miss 0.1", "OC-SORT miss 0.3", "OC-SORT (head detector)"]
    rows = list(csv.DictReader(io.StringIO((out / "table.csv").read_text())))
    assert "paper_acc@15" not in rows[0]
    assert [(r["method"], r["sequence"]) for r in rows] == [
        (label, s) for label in labels for s in ("a", "b")
    ]
    for r in rows:
        assert 0.0 <= float(r["acc@15"]) <= 100.0 and float(r["fps"]) > 0
    assert rows[0]["acc@15"] == rows[1]["acc@15"]  # the same frames, read from either folder
    assert (out / "curves" / "a.png").stat().st_size > 0
    assert not (out / "sequences").exists()
    assert _snapshot(mine) == before  # nothing written into the user's folder
    cells = json.loads((out / "cells.json").read_text())["cells"]
    assert len(cells) == 8 and all("frames=8" in k for k in cells)

    # a rerun resumes: no cell is tracked again, and the table is the same
    monkeypatch.setattr(experiments, "run_cell", lambda *a: pytest.fail("cell rerun"))
    assert main(argv) == 0
    assert (out / "table.md").read_text() == table

    # an edited gt.txt is another sequence: its cells are computed, the other's reused
    monkeypatch.undo()
    ran = []
    real = experiments.run_cell
    monkeypatch.setattr(
        experiments, "run_cell", lambda seq_dir, *a: ran.append(seq_dir) or real(seq_dir, *a)
    )
    gt = mine / "b" / "gt" / "gt.txt"
    lines = gt.read_text().splitlines()
    f, i, x, *rest = lines[-1].split(",")
    gt.write_text("\n".join([*lines[:-1], ",".join([f, i, str(float(x) + 1.0), *rest])]) + "\n")
    assert main(argv) == 0
    assert ran == [str(mine / "b")] * 4
    assert len(json.loads((out / "cells.json").read_text())["cells"]) == 12

    # --frames past the sequences' 10 frames finds the cells of a run without it
    monkeypatch.undo()
    whole = [a for a in argv if a not in ("--frames", "8")]
    assert main(whole) == 0
    monkeypatch.setattr(experiments, "run_cell", lambda *a: pytest.fail("cell rerun"))
    assert main([*whole, "--frames", "12"]) == 0


def test_compare_sequences_reads_a_video_sequence_and_one_sequence_folder(generated, tmp_path):
    """A sequence whose frames are ``video.mp4`` (no ``img1/``), given as the folder itself."""
    import cv2

    from crowdsim.cli import main
    from synth_data.mot import read_sequence

    seq = tmp_path / "vid"
    shutil.copytree(generated / "a", seq)
    (seq / "checksums.json").unlink()
    src = read_sequence(seq)
    writer = cv2.VideoWriter(
        str(seq / "video.mp4"), cv2.VideoWriter_fourcc(*"mp4v"), 25.0, (src.width, src.height)
    )
    for frame in src.frames():
        writer.write(frame)
    writer.release()
    shutil.rmtree(seq / "img1")
    out = tmp_path / "cmp"
    argv = ["compare", "--sequences", str(seq), "--trackers", "ncc", "--no-progress"]
    assert main([*argv, "--out", str(out)]) == 0
    rows = list(csv.DictReader(io.StringIO((out / "table.csv").read_text())))
    assert [(r["method"], r["sequence"]) for r in rows] == [("NCC", "vid")]
    assert float(rows[0]["acc@15"]) > 50.0


def _drop_frame_1_rows(s):
    gt = s / "gt" / "gt.txt"
    gt.write_text(
        "".join(ln + "\n" for ln in gt.read_text().splitlines() if ln.split(",")[0] != "1")
    )


def test_compare_sequences_tracks_people_born_after_frame_1_as_track_does(generated, tmp_path):
    """Nobody in frame 1: every person is born at their first frame, as ``track`` has it."""
    from crowdsim.cli import main

    mine = _user_folder(generated, tmp_path)
    _drop_frame_1_rows(mine / "b")
    out = tmp_path / "cmp"
    argv = ["compare", "--sequences", str(mine), "--only", "b", "--trackers", "ncc"]
    assert main([*argv, "--no-progress", "--out", str(out)]) == 0
    rows = list(csv.DictReader(io.StringIO((out / "table.csv").read_text())))
    assert [(r["method"], r["sequence"]) for r in rows] == [("NCC", "b")]
    assert float(rows[0]["acc@15"]) > 50.0


def _garbage_jpeg(s):
    (s / "img1" / "000004.jpg").write_bytes(b"not a jpeg")


def _garbage_video(s):
    shutil.rmtree(s / "img1")
    (s / "video.mp4").write_bytes(b"\x00" * 4096)


@pytest.mark.parametrize(
    "edit, where, needle",
    [
        (None, "mine", "no MOT sequence folders (sub-folders with seqinfo.ini)"),
        (
            lambda s: (s / "gt" / "gt.txt").unlink(),
            "mine/b",
            "no ground truth (gt/gt.txt) to score",
        ),
        (_garbage_jpeg, "mine/b/img1/000004.jpg", "not a complete image"),
        (lambda s: (s / "img1" / "000004.jpg").unlink(), "mine/b/img1/000004.jpg", "missing"),
        (_garbage_video, "mine/b/video.mp4", "could not read frame 1"),
    ],
    ids=["no-sequences", "no-gt", "unreadable-frame", "missing-frame", "video"],
)
def test_compare_sequences_refuses_bad_input_naming_the_path(
    generated, tmp_path, capsys, edit, where, needle
):
    """Exit 2 with one line naming the path, before any work: nothing written anywhere."""
    from crowdsim.cli import main

    mine = _user_folder(generated, tmp_path)
    if edit is None:  # no sequence at all: an empty folder
        shutil.rmtree(mine)
        mine.mkdir()
    else:
        edit(mine / "b")
    before = _snapshot(mine)
    out = tmp_path / "cmp"
    capsys.readouterr()
    argv = ["compare", "--sequences", str(mine), "--trackers", "ncc", "--no-progress"]
    assert main([*argv, "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err
    assert err.startswith("crowdsim compare: error: ")
    assert str(tmp_path / where) in err and needle in err
    assert not out.exists() and _snapshot(mine) == before


def test_compare_sequences_refuses_bad_flags(generated, tmp_path, capsys):
    """An ``--out`` inside the user's folder, a missing folder, an unknown ``--only`` and
    ``--suite`` beside ``--sequences``: exit 2, one line naming them."""
    from crowdsim.cli import main

    mine = _user_folder(generated, tmp_path)
    base = ["compare", "--trackers", "ncc", "--no-progress"]
    cases = [
        (["--sequences", str(mine), "--out", str(mine / "o")], f"--out {mine / 'o'}: inside"),
        (["--sequences", str(mine), "--out", str(mine)], "inside --sequences"),
        (["--sequences", str(tmp_path / "none"), "--out", str(tmp_path / "o")], "none: no such"),
        (
            ["--sequences", str(mine), "--only", "c", "--out", str(tmp_path / "o")],
            f"no sequence 'c' in {mine}; choose from a, b",
        ),
        (
            ["--suite", "ucf9", "--sequences", str(mine), "--out", str(tmp_path / "o")],
            "argument --sequences: not allowed with argument --suite",
        ),
    ]
    for argv, needle in cases:
        capsys.readouterr()
        with pytest.raises(SystemExit) if "--suite" in argv else contextlib.nullcontext():
            assert main([*base, *argv]) == 2
        err = capsys.readouterr().err
        assert needle in err, err
    assert not (tmp_path / "o").exists() and not (mine / "o").exists()


def test_compare_sequences_never_writes_into_a_sequence_linked_in(generated, tmp_path, capsys):
    """An ``--out`` inside a sequence that the ``--sequences`` folder holds as a symbolic link
    (a folder of links to one's footage) is refused like one inside the folder itself."""
    from crowdsim.cli import main

    mine = _user_folder(generated, tmp_path)
    links = tmp_path / "links"
    links.mkdir()
    (links / "a").symlink_to(mine / "a", target_is_directory=True)
    before = _snapshot(mine)
    capsys.readouterr()
    out = mine / "a" / "res"
    argv = ["compare", "--sequences", str(links), "--trackers", "ncc", "--no-progress"]
    assert main([*argv, "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert f"--out {out}: inside sequence {links / 'a'}" in err, err
    assert not out.exists() and _snapshot(mine) == before


def test_a_sequences_digest_follows_its_files_without_decoding_them(generated, tmp_path):
    """:func:`~crowdsim.lab.experiments.sequence_digest`: the same folder read twice is the
    same digest; an edited seqinfo.ini, a frame copied over with another of the same size
    or a frame removed is another."""
    import os

    from crowdsim.lab.experiments import sequence_digest
    from synth_data.mot import read_sequence

    seq = _user_folder(generated, tmp_path) / "b"
    first = sequence_digest(read_sequence(seq))
    assert sequence_digest(read_sequence(seq)) == first
    frame = seq / "img1" / "000002.jpg"
    st = frame.stat()
    frame.write_bytes(frame.read_bytes()[::-1])  # the same size, other bytes
    os.utime(frame, ns=(st.st_atime_ns, st.st_mtime_ns + 1))
    second = sequence_digest(read_sequence(seq))
    assert second != first
    (seq / "seqinfo.ini").write_text((seq / "seqinfo.ini").read_text() + "\n")
    third = sequence_digest(read_sequence(seq))
    assert third not in (first, second)
    (seq / "img1" / "000010.jpg").unlink()
    assert sequence_digest(read_sequence(seq)) not in (first, second, third)


def test_a_table_put_at_out_while_cells_run_is_kept(tmp_path, monkeypatch):
    """The outputs are checked before the work; a ``table.md`` the user puts there while the
    cells run is theirs: kept, the run refused by name before its record commits, and the
    record never vouches for it."""
    out = tmp_path / "t"
    real = experiments.run_cell

    def cell_while_the_user_writes(*a, **k):
        (out / "table.md").write_text("my notes\n")
        return real(*a, **k)

    monkeypatch.setattr(experiments, "run_cell", cell_while_the_user_writes)
    with pytest.raises(FileExistsError, match="table.md: a file appeared there"):
        run_table(ROWS, [tiny("a")], out, progress=False, log=lambda m: None)
    assert (out / "table.md").read_text() == "my notes\n"
    assert not [p.name for p in out.iterdir() if p.name.startswith(".table")]
    monkeypatch.undo()
    with pytest.raises(ValueError, match="table.md exists and was not written by"):
        run_table(ROWS, [tiny("a")], out, progress=False, log=lambda m: None)


def test_two_runs_sharing_out_both_finish_and_a_users_table_is_still_kept(tmp_path, monkeypatch):
    """Two ``compare`` runs on one ``--out`` at once: the one finishing second replaces the
    tables the first wrote meanwhile (its record lists them), rather than refusing them as a
    user's (it had ended "a file appeared there", exit 2); a user's file is still kept."""
    import crowdsim.atomic

    out = tmp_path / "t"
    monkeypatch.setattr(experiments, "run_cell", _fake_cell)
    other_ran = []

    def cell_while_another_run_finishes(*a, **k):
        if not other_ran:  # the other process: its checks and writes are not this one's
            other_ran.append(True)
            mine = dict(crowdsim.atomic._CHECKED)
            run_table(ROWS, [tiny("a")], out, progress=False, log=lambda m: None)
            crowdsim.atomic._CHECKED.clear()
            crowdsim.atomic._CHECKED.update(mine)
        return _fake_cell(*a, **k)

    monkeypatch.setattr(experiments, "run_cell", cell_while_another_run_finishes)
    first = run_table(ROWS, [tiny("a")], out, progress=False, log=lambda m: None)
    assert other_ran and (out / "table.md").read_text() == first
    monkeypatch.setattr(experiments, "run_cell", _fake_cell)
    assert run_table(ROWS, [tiny("a")], out, progress=False, log=lambda m: None) == first
    (out / "cells.json").unlink()

    def cell_while_the_user_writes(*a, **k):
        (out / "table.md").write_text("my notes\n")
        return _fake_cell(*a, **k)

    monkeypatch.setattr(experiments, "run_cell", cell_while_the_user_writes)
    with pytest.raises(FileExistsError, match="table.md: a file appeared there"):
        run_table(ROWS, [tiny("a")], out, progress=False, log=lambda m: None)
    assert (out / "table.md").read_text() == "my notes\n"
