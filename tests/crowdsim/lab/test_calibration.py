"""``crowdsim calibrate`` with a fake scorer: the bracketing, the figures it reports and
writes, the calibrated suite folder, the suite's own specs and the study files it refuses."""

from __future__ import annotations

import json
import sqlite3
from pathlib import Path

import numpy as np
import optuna
import pytest

from crowdsim.cli import main
from crowdsim.jobs import Interrupted
from crowdsim.knobs import knob
from crowdsim.lab import calibration
from synth_data.spec import load_spec, parse_spec_text, spec_from_dict
from synth_data.suites import paper_numbers, suite_dir, suite_specs

SPEC = """# {name}: a hand-written spec; comments survive calibration
name = "{name}"
seed = {seed}
frames = 6

[scenario]
name = "crossing"  # two groups
n_agents = 10

[camera]
px_per_m = 14.0

[appearance]
template_px = 8
noise_sigma = 3.0

[calibration]
paper_b_ncc_15px = {target}
{extra}"""


def _curve(d: float) -> float:
    """The fake NCC score (%) at difficulty ``d``: falls non-linearly, so bracketing and
    bisection place their trials differently."""
    return 90.0 - 80.0 * d * d


def _difficulty(spec) -> float:
    """The difficulty a scored spec was rendered at: dark_hair_fraction runs from 0 (these
    specs) to its hard end 1 on the scale, so it *is* d (rounded to the knob's digits)."""
    assert knob("dark_hair_fraction").hard == 1.0
    return float(spec.appearance.dark_hair_fraction)


@pytest.fixture
def scored(monkeypatch):
    """Replace the NCC scorer by :func:`_curve`; the list records every difficulty scored."""
    calls: list[float] = []

    def fake(spec, workdir, anchor="b-ncc"):
        d = _difficulty(spec)
        calls.append(d)
        return _curve(d)

    monkeypatch.setattr(calibration, "score", fake)
    return calls


def _suite(root: Path, **targets: float | tuple[float, str]) -> Path:
    root.mkdir(parents=True)
    for i, (name, t) in enumerate(targets.items()):
        target, extra = t if isinstance(t, tuple) else (t, "")
        (root / f"{name}.toml").write_text(
            SPEC.format(name=name, seed=i + 1, target=target, extra=extra)
        )
    ncc = {k: t[0] if isinstance(t, tuple) else t for k, t in targets.items()}
    (root / "paper.json").write_text(json.dumps({"acc@15": {"NCC": ncc}}))
    return root


@pytest.fixture
def suite(tmp_path) -> Path:
    """Sequences ``a`` (paper 60 %) and ``b`` (paper 78.5 %, its spec records 80 achieved)."""
    return _suite(tmp_path / "suite", a=60.0, b=(78.5, "achieved_b_ncc_15px = 80.0\n"))


def test_bracketing_uses_the_scores_and_reports_the_measured_score(suite, scored):
    (spec,) = suite_specs(suite, ["a"])
    res = calibration.calibrate_spec(spec, 60.0, trials=4, log=lambda m: None)
    # by hand: d = 0 -> 90, d = 1 -> 10; regula falsi in [0, 1]: (90 - 60) / 80 = 0.375 ->
    # 78.75; in [0.375, 1]: 0.375 + 18.75 / 68.75 * 0.625 = 0.54545, rendered at 0.5455 (the
    # knob's 4 digits) -> 66.194
    want = [0.0, 1.0, 0.375, 0.375 + 18.75 / 68.75 * 0.625]
    np.testing.assert_allclose(scored, want, atol=1e-4)
    best = scored[3]
    assert res["difficulty"] == pytest.approx(best, abs=1e-4)
    assert res["score_15px"] == round(_curve(best), 2) == 66.19  # measured, above the target
    assert res["error"] == 6.19
    assert res["trials"] == 4
    assert res["values"][("appearance", "dark_hair_fraction")] == round(best, 4)


def test_a_study_stops_within_tolerance_and_a_harder_spec_is_not_searched(suite, scored):
    (spec,) = suite_specs(suite, ["a"])
    res = calibration.calibrate_spec(spec, 78.5, trials=12, log=lambda m: None)
    assert scored[:3] == pytest.approx([0.0, 1.0, 0.14375], abs=1e-4)  # (90 - 78.5) / 80
    assert len(scored) == res["trials"] and abs(res["score_15px"] - 78.5) <= calibration.TOLERANCE
    scored.clear()
    res = calibration.calibrate_spec(spec, 95.0, trials=12, log=lambda m: None)
    assert scored == [0.0] and res["difficulty"] == 0.0 and res["score_15px"] == 90.0


def _tree(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in folder.rglob("*") if p.is_file()}


def test_calibrate_writes_a_new_suite_folder_and_leaves_the_suite_alone(suite, tmp_path, scored):
    before = _tree(suite)
    out = tmp_path / "cal"
    res = calibration.calibrate_suite(suite, out=out, trials=4, log=lambda m: None)
    assert _tree(suite) == before  # the suite calibrated from is untouched
    assert set(res) == {"a", "b"} and res["a"]["suite_spec"] is None
    assert sorted(p.name for p in out.iterdir()) == [
        "README.md",
        "a.toml",
        "b.toml",
        "calibrate.json",
        "calibration.db",
        "paper.json",
    ]
    a = load_spec(out / "a.toml")
    measured = round(_curve(scored[3]), 2)
    assert res["a"]["score_15px"] == a.calibration["achieved_b_ncc_15px"] == measured
    assert a.appearance.dark_hair_fraction == round(scored[3], 4)
    assert (out / "a.toml").read_text().startswith("# a: a hand-written spec")
    assert "# two groups" in (out / "a.toml").read_text()
    readme = (out / "README.md").read_text()
    assert f"| a | crossing | 10 | 8 | b-ncc | 60.0 | {measured} |" in readme
    assert calibration.README_MARK in readme
    # the folder is a suite: its specs, its paper figures, a calibrate source
    assert [s.name for s in suite_specs(out)] == ["a", "b"]
    assert paper_numbers(out) == paper_numbers(suite)
    record = json.loads((out / "calibrate.json").read_text())
    assert record["source"] == str(suite.resolve()) and record["results"]["a"] == res["a"]
    gen = tmp_path / "gen"
    assert main(["generate", "--suite", str(out), "--out", str(gen), "--no-progress"]) == 0
    meta = json.loads((gen / "a" / "meta.json").read_text())
    assert meta["appearance"]["dark_hair_fraction"] == a.appearance.dark_hair_fraction
    # a rerun resumes: no trial again, the same files
    scored.clear()
    again = calibration.calibrate_suite(suite, out=out, trials=4, log=lambda m: None)
    assert scored == [] and again == res


def test_cli_refuses_what_it_did_not_write(suite, tmp_path, scored, capsys):
    out = tmp_path / "cal"
    assert main(["calibrate", "--suite", str(suite), "--out", str(out), "--trials", "2"]) == 0
    assert "calibrated suite -> " in capsys.readouterr().err
    (out / "a.toml").write_text((out / "a.toml").read_text() + "# my note\n")
    edited = _tree(out)
    assert main(["calibrate", "--suite", str(suite), "--out", str(out), "--trials", "3"]) == 2
    err = capsys.readouterr().err
    assert "a.toml: not written by crowdsim calibrate, or changed since" in err
    assert _tree(out) == edited
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "notes.txt").write_text("mine")
    assert main(["calibrate", "--suite", str(suite), "--out", str(mine)]) == 2
    assert "not empty and not written by crowdsim calibrate" in capsys.readouterr().err
    assert main(["calibrate", "--suite", str(suite), "--out", str(suite)]) == 2
    assert "is the suite folder itself" in capsys.readouterr().err
    assert main(["calibrate", "--suite", "ucf9", "--out", str(out)]) == 2
    assert "holds a calibration of the suite" in capsys.readouterr().err
    assert _tree(out) == edited and sorted(p.name for p in mine.iterdir()) == ["notes.txt"]


def test_update_suite_keeps_a_better_calibration_unless_forced(suite, tmp_path, scored):
    logs: list[str] = []
    # b's spec records 80.0 for a target of 78.5 (1.5 off); 2 trials reach 90 / 10 only
    res = calibration.calibrate_suite(
        suite, out=tmp_path / "o1", trials=2, update_suite=True, log=logs.append
    )
    assert res["b"]["suite_spec"] == "kept" and res["a"]["suite_spec"] == "updated"
    assert any(m.startswith("b: kept the suite's calibration") for m in logs)
    assert load_spec(suite / "b.toml").calibration["achieved_b_ncc_15px"] == 80.0
    assert load_spec(suite / "a.toml").calibration["achieved_b_ncc_15px"] == res["a"]["score_15px"]
    assert calibration.README_MARK in (suite / "README.md").read_text()
    # --force writes the worse one
    res = calibration.calibrate_suite(
        suite, out=tmp_path / "o2", only=["b"], trials=2, update_suite=True, force=True,
        log=logs.append,
    )  # fmt: skip
    assert res["b"]["suite_spec"] == "updated"
    assert load_spec(suite / "b.toml").calibration["achieved_b_ncc_15px"] == res["b"]["score_15px"]
    with pytest.raises(ValueError, match="--force needs --update-suite"):
        calibration.calibrate_suite(suite, out=tmp_path / "o3", force=True)


def test_a_users_readme_is_never_replaced(suite, tmp_path, scored):
    (suite / "README.md").write_text("# my own notes\n")
    logs: list[str] = []
    calibration.calibrate_suite(
        suite, out=tmp_path / "o", trials=1, update_suite=True, log=logs.append
    )
    assert (suite / "README.md").read_text() == "# my own notes\n"
    assert any("not written by crowdsim calibrate; left unchanged" in m for m in logs)


def _optuna_db(path: Path, marked: bool) -> None:
    study = optuna.create_study(storage=f"sqlite:///{path}", study_name="someone-elses")
    if marked:
        study.set_user_attr(calibration.STUDY_ATTR, {"sequence": "x", "digest": "y"})


@pytest.mark.parametrize(
    "content, needle",
    [
        (b"not a database at all\n", "not an SQLite file"),
        ("people", r"an SQLite database that is not an Optuna study \(tables people\)"),
        ("optuna", "holds the Optuna study 'someone-elses', not made by crowdsim calibrate"),
    ],
)
def test_foreign_study_files_are_refused_and_left_alone(suite, tmp_path, scored, content, needle):
    db = tmp_path / "s.db"
    if content == "people":
        con = sqlite3.connect(db)
        con.execute("CREATE TABLE people (id INTEGER)")
        con.commit()
        con.close()
    elif content == "optuna":
        _optuna_db(db, marked=False)
    else:
        db.write_bytes(content)
    before = db.read_bytes()
    out = tmp_path / "o"
    with pytest.raises(ValueError, match=needle):
        calibration.calibrate_suite(suite, out=out, study=db, log=lambda m: None)
    assert db.read_bytes() == before and not out.exists() and scored == []
    with pytest.raises(ValueError, match=needle):  # the API checks its storage too
        spec = suite_specs(suite, ["a"])[0]
        calibration.calibrate_spec(spec, 60.0, storage=f"sqlite:///{db}", log=lambda m: None)
    assert db.read_bytes() == before


def test_a_calibrate_study_file_is_accepted(suite, tmp_path, scored):
    db = tmp_path / "s.db"
    _optuna_db(db, marked=True)
    calibration.calibrate_suite(suite, out=tmp_path / "o", study=db, trials=1)
    names = {s.study_name for s in optuna.get_all_study_summaries(f"sqlite:///{db}")}
    assert len(names) == 3  # the marked one and a study per sequence


@pytest.mark.parametrize("signal_name, code", [("SIGTERM", 143), ("SIGINT", 130)])
def test_an_interrupted_trial_ends_in_one_line(
    suite, tmp_path, monkeypatch, capfd, signal_name, code
):
    calls = []

    def fake(spec, workdir, anchor="b-ncc"):
        calls.append(_difficulty(spec))
        if len(calls) == 2:
            raise Interrupted(signal_name)
        return _curve(calls[-1])

    monkeypatch.setattr(calibration, "score", fake)
    out = tmp_path / "o"
    argv = ["calibrate", "--suite", str(suite), "--only", "a", "--out", str(out)]
    assert main(argv) == code
    lines = capfd.readouterr().err.strip().splitlines()
    assert lines[0].startswith("a: trial 0: difficulty 0.000 -> b-ncc 90.0%")
    assert len(lines) == 2 and "Traceback" not in lines[1], lines
    assert lines[1].startswith(f"crowdsim calibrate: interrupted by {signal_name}; ")
    assert "rerun the same command to resume" in lines[1]
    (summary,) = [
        s
        for s in optuna.get_all_study_summaries(f"sqlite:///{out / 'calibration.db'}")
        if s.study_name.startswith("calibrate-b-ncc-a-")
    ]
    study = optuna.load_study(
        study_name=summary.study_name, storage=f"sqlite:///{out / 'calibration.db'}"
    )
    states = [t.state.name for t in study.trials]
    assert states == ["COMPLETE", "FAIL"]
    # a rerun resumes from the finished trial
    calls.clear()
    monkeypatch.setattr(calibration, "score", lambda spec, w, anchor=None: calls.append(1) or 10.0)
    assert main([*argv, "--trials", "2"]) == 0
    assert len(calls) == 1


def test_a_study_storage_that_fills_mid_run_ends_in_one_line(
    suite, tmp_path, monkeypatch, capfd, scored, study_disk_full
):
    real, told = optuna.Study.tell, []

    def tell(self, *args, **kwargs):
        told.append(1)
        if len(told) == 2:  # the second trial's result meets a full disk
            study_disk_full()
        return real(self, *args, **kwargs)

    monkeypatch.setattr(optuna.Study, "tell", tell)
    db = tmp_path / "o" / "calibration.db"
    argv = ["calibrate", "--suite", str(suite), "--only", "a", "--out", str(tmp_path / "o")]
    assert main(argv) == 2
    lines = capfd.readouterr().err.strip().splitlines()
    assert "Traceback" not in "\n".join(lines), lines
    assert lines[-1] == (
        f"crowdsim calibrate: error: {db}: the study storage failed: database or disk is full"
    )


def test_suite_folders_are_named_clearly(tmp_path):
    with pytest.raises(ValueError, match=r"got '.*nowhere' \(no such folder\)"):
        suite_specs(tmp_path / "nowhere")
    (tmp_path / "f.toml").write_text("")
    with pytest.raises(ValueError, match="is a file, not a suite folder"):
        suite_dir(tmp_path / "f.toml")
    empty = tmp_path / "empty"
    (empty / "seqA").mkdir(parents=True)
    (empty / "seqA" / "seqinfo.ini").write_text("[Sequence]\n")
    with pytest.raises(
        ValueError, match=r"no spec files \(\*.toml, \*.yaml, \*.yml\).*tune and heldout"
    ):
        suite_specs(empty)
    assert suite_dir("ucf9").name == "ucf9"  # a built-in name wins


def test_the_closest_measured_trial_is_reported_not_the_last(suite, monkeypatch):
    scores = iter([90.0, 10.0, 62.0, 55.0])  # noisy: the last trial lands further off
    tried = []

    def fake(spec, workdir, anchor="b-ncc"):
        tried.append(_difficulty(spec))
        return next(scores)

    monkeypatch.setattr(calibration, "score", fake)
    (spec,) = suite_specs(suite, ["a"])
    res = calibration.calibrate_spec(spec, 60.0, trials=4, log=lambda m: None)
    # 62 at d = 30 / 80 = 0.375; then [0.375, 1]: f = 2 / 52 < 0.1 -> d = 0.4375 -> 55
    assert tried == pytest.approx([0.0, 1.0, 0.375, 0.4375], abs=1e-4)
    assert (res["difficulty"], res["score_15px"], res["error"]) == (0.375, 62.0, 2.0)


def test_the_anchor_picks_target_tracker_and_profile(suite, tmp_path, monkeypatch):
    """b-ncc scores with BQP's appearance term only (NCC) on the static profile: no shake, no
    camera motion blur at any difficulty; ncc11 scores with the NCC tracker up to the hard
    ends. The spec records the anchor, and another anchor's achieved score is dropped."""
    seen: list[tuple[str, float, float]] = []

    def fake(spec, workdir, anchor="b-ncc"):
        app = spec.appearance
        seen.append(
            (anchor, spec.camera.get("jitter_px", 0.0), app.motion_blur_px, app.noise_sigma)
        )
        return _curve(_difficulty(spec))

    monkeypatch.setattr(calibration, "score", fake)
    (spec,) = suite_specs(suite, ["b"])  # its spec records an ncc11 calibration (80 achieved)
    static = calibration.calibrate_spec(spec, 60.0, trials=3, log=lambda m: None)
    assert {a for a, *_ in seen} == {"b-ncc"} and {(j, b) for _, j, b, _ in seen} == {(0.0, 0.0)}
    assert seen[1][3] == knob("noise_sigma").static  # d = 1: a realistic end
    seen.clear()
    hard = calibration.calibrate_spec(spec, 60.0, anchor="ncc11", trials=3, log=lambda m: None)
    assert {a for a, *_ in seen} == {"ncc11"} and hard["anchor"] == "ncc11"
    ends = (knob("jitter_px").hard, knob("motion_blur_px").hard, knob("noise_sigma").hard)
    assert seen[1][1:] == ends  # d = 1: every knob at its hard end

    text = (suite / "b.toml").read_text().replace("achieved_b_ncc_15px", "achieved_ncc_15px")
    new = calibration.calibrated_text(text, static)
    written = spec_from_dict(parse_spec_text(new, "toml", "b.toml"), source="b.toml").calibration
    assert written["anchor"] == "b-ncc" and written["achieved_b_ncc_15px"] == static["score_15px"]
    assert "achieved_ncc_15px" not in written  # it described knobs that are gone
    bncc = calibration.ANCHORS["b-ncc"]
    assert (bncc.tracker, bncc.overrides["appearance"]) == ("bqp", "ncc")
    assert all(bncc.overrides[w] == 0.0 for w in ("zeta", "eta", "w_sp", "w_g"))


def test_the_b_ncc_anchor_is_paper_ones_table_3_row_in_the_suite():
    """Every ucf9 spec's b-ncc target is Table 3's B(NCC) figure of its sequence."""
    table = paper_numbers("ucf9")["ablation@15"]["B (NCC)"]
    for spec in suite_specs("ucf9"):
        assert spec.calibration["paper_b_ncc_15px"] == table[spec.name], spec.name
    for spec in suite_specs("ucf9-shake"):  # the earlier calibration, kept as a variant
        assert spec.calibration["anchor"] == "ncc11" and spec.camera["jitter_px"] > 0


def test_ucf9_drone_is_ucf9_with_the_drone_camera_and_nothing_else():
    """ucf9-drone is a copy: a recalibrated ucf9 must be copied over (this fails until it is)."""
    from dataclasses import replace

    drone = {"drift_px": 24.0, "rotate_deg": 3.0, "zoom": 0.05, "drone_frames": 150.0}
    base = {s.name: s for s in suite_specs("ucf9")}
    specs = suite_specs("ucf9-drone")
    assert [s.name for s in specs] == list(base)
    for spec in specs:
        assert {k: spec.camera[k] for k in drone} == drone, spec.name
        camera = {k: v for k, v in spec.camera.items() if k not in drone}
        assert replace(spec, camera=camera, source="") == replace(base[spec.name], source="")


def test_a_changed_anchor_tracker_is_a_new_study_not_a_resumed_one(
    suite, tmp_path, scored, monkeypatch
):
    """The study's key holds the anchor tracker's complete parameters, as a compare cell's
    does: trials scored with other parameters (a changed default) are never reused."""
    from dataclasses import replace

    (spec,) = suite_specs(suite, ["a"])
    storage = f"sqlite:///{tmp_path / 's.db'}"
    first = calibration.calibrate_spec(spec, 60.0, trials=2, storage=storage, log=lambda m: None)
    assert first["trials"] == 2 and scored == [0.0, 1.0]
    scored.clear()
    again = calibration.calibrate_spec(spec, 60.0, trials=2, storage=storage, log=lambda m: None)
    assert again == first and scored == []  # resumed: nothing rescored
    a = calibration.ANCHORS["b-ncc"]
    other = replace(a, overrides={**a.overrides, "w_g": 0.5})
    before = calibration.study_name(spec)
    monkeypatch.setitem(calibration.ANCHORS, "b-ncc", other)
    assert calibration.study_name(spec) != before
    new = calibration.calibrate_spec(spec, 60.0, trials=1, storage=storage, log=lambda m: None)
    assert scored == [0.0] and new["trials"] == 1  # a fresh study, the old trials unused


def test_help_reads_without_sphinx_roles(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["calibrate", "--help"])
    out = capsys.readouterr().out
    assert exc.value.code == 0 and ":mod:" not in out and "crowdsim.lab.calibration)" in out


@pytest.mark.parametrize(
    "value, needle",
    [
        ("nan", "calibration.base_appearance_noise_sigma must be a finite number in [0, 50], "
         "got nan"),
        ('"abc"', "calibration.base_appearance_noise_sigma must be a finite number in [0, 50], "
         "got 'abc'"),
        ("400", "calibration.base_appearance_noise_sigma must be a finite number in [0, 50], "
         "got 400"),
    ],
)  # fmt: skip
def test_a_bad_recorded_base_value_is_refused_by_name_before_any_write(
    tmp_path, scored, capsys, value, needle
):
    """A spec's base_* value (its knobs before the first calibration) out of its knob's range
    is named with its file and field; it had failed after --out was written ('could not
    convert string to float: 'abc'', or 'appearance.noise_sigma ... got nan' naming no file)."""
    suite = _suite(tmp_path / "s", a=(60.0, f"base_appearance_noise_sigma = {value}\n"))
    out = tmp_path / "cal"
    assert main(["calibrate", "--suite", str(suite), "--out", str(out), "--trials", "1"]) == 2
    err = capsys.readouterr().err
    assert f"{suite / 'a.toml'}: {needle}" in err
    assert not out.exists() and scored == []


def test_a_misspelt_base_key_is_refused_by_name_before_any_write(tmp_path, scored, capsys):
    """``base_appearance_noise_sigm`` records no knob: it had been ignored, and noise's search
    started from the calibrated value in silence."""
    suite = _suite(tmp_path / "s", a=(60.0, "base_appearance_noise_sigm = 4.0\n"))
    out = tmp_path / "cal"
    assert main(["calibrate", "--suite", str(suite), "--out", str(out), "--trials", "1"]) == 2
    err = capsys.readouterr().err
    assert "calibration.base_appearance_noise_sigm records no difficulty knob's value" in err
    assert "base_appearance_noise_sigma" in err and not out.exists() and scored == []


def test_only_naming_a_sequence_without_the_anchors_figure_refuses_it(tmp_path, scored):
    """``--only a b`` where b records no paper_b_ncc_15px had calibrated a alone, in silence."""
    suite = _suite(tmp_path / "s", a=60.0, b=70.0)
    text = (suite / "b.toml").read_text().replace("paper_b_ncc_15px = 70.0\n", "")
    (suite / "b.toml").write_text(text + "paper_ncc_15px = 50.0\n")
    with pytest.raises(ValueError, match=r"--only b: no \[calibration\] paper_b_ncc_15px"):
        calibration.calibrate_suite(suite, out=tmp_path / "cal", only=["a", "b"], trials=1)
    assert not (tmp_path / "cal").exists() and scored == []
    res = calibration.calibrate_suite(suite, out=tmp_path / "cal", trials=1, log=lambda m: None)
    assert set(res) == {"a"}  # the whole suite: the sequences with a figure, as documented


def test_a_spec_edited_during_the_run_is_kept_and_not_mixed_with_the_results(
    suite, tmp_path, monkeypatch
):
    """--update-suite read the suite's spec again at the write: an edit made while the trials
    ran (here 10 -> 12 people) got the calibration of the spec before it, and so did --out's."""
    path = suite / "a.toml"

    def fake(spec, workdir, anchor="b-ncc"):
        text = path.read_text()
        if "n_agents = 10" in text:
            path.write_text(text.replace("n_agents = 10", "n_agents = 12"))
        return _curve(_difficulty(spec))

    monkeypatch.setattr(calibration, "score", fake)
    logs: list[str] = []
    res = calibration.calibrate_suite(
        suite, out=tmp_path / "cal", only=["a"], trials=2, update_suite=True, log=logs.append
    )
    assert res["a"]["suite_spec"] == "kept"
    assert any(m.startswith("a: kept") and "changed since this run read it" in m for m in logs)
    edited = load_spec(path)
    assert edited.scenario["n_agents"] == 12 and "achieved_b_ncc_15px" not in edited.calibration
    written = load_spec(tmp_path / "cal" / "a.toml")  # the spec calibrated, with its results
    assert written.scenario["n_agents"] == 10
    assert written.calibration["achieved_b_ncc_15px"] == res["a"]["score_15px"]
