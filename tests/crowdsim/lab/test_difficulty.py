"""Difficulty attribution: one knob group reset at a time, exact spec variants, and a tiny
end-to-end run whose figures come from the table's own cells."""

from __future__ import annotations

import json
import re

import pytest

from crowdsim.cli import main
from crowdsim.lab.calibration import _uncalibrated
from crowdsim.lab.difficulty import DIFFICULTY_GROUPS, attribute, ground_margin, variant_specs
from crowdsim.lab.experiments import Row, cell_key
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
        # seq9 shakes by 0.28 px calibrated, 0.5 px uncalibrated: 3 px of ground either way
        assert ground_margin(v) == ground_margin(spec) == 3 and "ground_margin_px" not in v.camera
    assert len({v.name for v in variants.values()}) == len(variants)


def test_a_knob_newer_than_the_calibration_keeps_its_value():
    """A knob added after a spec was calibrated has no base_* value: its group's variant
    keeps the spec's own value (it had raised KeyError, a traceback from difficulty)."""
    from dataclasses import replace

    (spec,) = suite_specs("ucf9", ["seq9"])
    group, names = next(iter(DIFFICULTY_GROUPS.items()))
    newer = names[0]
    cal = {k: v for k, v in spec.calibration.items() if not k.endswith(f"_{newer}")}
    assert len(cal) == len(spec.calibration) - 1
    variants = dict(variant_specs(replace(spec, calibration=cal)))
    assert _knobs(variants[f"-{group}"])[newer] == _knobs(spec)[newer]


def test_the_still_twin_of_a_shaken_spec_draws_its_ground():
    """ucf9-shake's seq4 shakes by 1.59 px, uncalibrated not at all: its -shake variant keeps
    the 8 px of ground the shake needs, so the two render the same ground and differ by the
    shake alone; the uncalibrated spec renders as it would on its own."""
    (spec,) = suite_specs("ucf9-shake", ["seq4"])
    variants = dict(variant_specs(spec))
    assert ground_margin(spec) == 8
    still = variants["-shake"]
    assert still.camera["jitter_px"] == 0.0 and still.camera["ground_margin_px"] == 8
    for label, v in variants.items():
        assert ground_margin(v) == (0 if label == "uncalibrated" else 8), label
        if label != "-shake":
            assert "ground_margin_px" not in v.camera, label


def test_groups_limit_the_variants_in_table_order():
    (spec,) = suite_specs("ucf9", ["seq9"])
    names = [v for v, _ in variant_specs(spec, ["shake", "blur"])]
    assert names == ["calibrated", "-blur", "-shake", "uncalibrated"]
    with pytest.raises(ValueError, match="unknown group 'wobble'"):
        variant_specs(spec, ["wobble"])


def test_cmc_rows_report_what_compensation_regains_of_shake(tmp_path):
    doc = attribute(
        "ucf9-shake",
        tmp_path,
        only=["seq9"],
        trackers=["ncc"],
        groups=["shake"],
        cmc=True,
        frames=8,
        progress=False,
        log=print,
    )
    cells = json.loads((tmp_path / "cells.json").read_text())["cells"]
    assert len(cells) == 6  # calibrated, -shake, uncalibrated; with and without cmc
    cells = {re.sub(r"@[0-9a-f]{12}\|", "|", k): c for k, c in cells.items()}  # by name
    acc = {
        (v, c): cells[cell_key(v, Row("x", "ncc", {"cmc": True} if c else {}), 8)]["acc@15"]
        for v in ("seq9.calibrated", "seq9.no-shake")
        for c in (False, True)
    }
    per = doc["sequences"]["seq9"]
    assert set(per) == {"ncc", "ncc+cmc"} and list(doc["groups"]) == ["shake"]
    r = per["ncc"]
    assert r["cmc"] == pytest.approx(
        acc[("seq9.calibrated", True)] - acc[("seq9.calibrated", False)]
    )
    shake = acc[("seq9.no-shake", False)] - acc[("seq9.calibrated", False)]
    assert r["regained"]["shake"] == pytest.approx(shake)
    if shake > 0:
        assert r["cmc_share_of_shake"] == pytest.approx(r["cmc"] / shake)
    else:
        assert "cmc_share_of_shake" not in r
    text = (tmp_path / "attribution.md").read_text()
    assert "| +cmc | cmc / shake |" in text and "| seq9 | ncc+cmc |" in text


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
    assert "| mean |" not in (tmp_path / "table.md").read_text()  # columns are variants
    acc = {k.split("|")[0].split("@")[0]: v["acc@15"] for k, v in cells.items()}
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


def test_a_suite_folder_with_never_calibrated_specs_attributes_the_calibrated_ones(
    tmp_path, monkeypatch
):
    """A folder such as ``calibrate --only seq9`` writes (the other specs copied with only
    their papers' figures) attributes its calibrated sequences; it had refused the whole
    suite, naming the uncalibrated copy. A sequence named in ``--only`` is still refused."""
    import shutil

    import crowdsim.lab.experiments as experiments
    from synth_data.suites import suite_dir

    suite = tmp_path / "s"
    suite.mkdir()
    shutil.copy(suite_dir("ucf9") / "seq9.toml", suite / "seq9.toml")
    text = (suite_dir("ucf9") / "seq2.toml").read_text()
    head = text[: text.index("[calibration]")]
    (suite / "seq2.toml").write_text(head + "[calibration]\npaper_b_ncc_15px = 98.54\n")
    ran = []
    monkeypatch.setattr(experiments, "run_table", lambda rows, specs, *a, **k: ran.extend(specs))
    said = []
    doc = attribute(suite, tmp_path / "o", trackers=["ncc"], groups=["shake"], log=said.append)
    assert doc["groups"] == {"shake": DIFFICULTY_GROUPS["shake"]}
    assert {s.name.split(".")[0] for s in ran} == {"seq9"}
    assert any("not calibrated, left out: seq2" in m for m in said)
    with pytest.raises(ValueError, match="seq2: not calibrated"):
        attribute(suite, tmp_path / "o", only=["seq2"], trackers=["ncc"], log=said.append)


def test_help_names_no_flag_difficulty_lacks(capsys):
    """difficulty has no --sequences; its --out help had said 'not with --sequences'."""
    with pytest.raises(SystemExit) as exc:
        main(["difficulty", "--help"])
    out = capsys.readouterr().out
    assert exc.value.code == 0 and "--sequences" not in out and "attribution.md" in out


def test_only_naming_a_spec_without_a_calibration_section_refuses_it(tmp_path, monkeypatch):
    """``--only`` naming a spec with no ``[calibration]`` at all (a spec of one's own) beside a
    calibrated one refuses it by name, as one with only the papers' figures is; it had been
    dropped in silence and the table ran without it."""
    import shutil

    import crowdsim.lab.experiments as experiments
    from synth_data.suites import suite_dir

    suite = tmp_path / "s"
    suite.mkdir()
    shutil.copy(suite_dir("ucf9") / "seq9.toml", suite / "seq9.toml")
    text = (suite_dir("ucf9") / "seq2.toml").read_text()
    (suite / "seq2.toml").write_text(text[: text.index("[calibration]")])
    monkeypatch.setattr(experiments, "run_table", lambda *a, **k: None)
    with pytest.raises(ValueError, match="seq2: not calibrated"):
        attribute(
            suite, tmp_path / "o", only=["seq9", "seq2"], trackers=["ncc"], log=lambda m: None
        )


@pytest.mark.parametrize("tracker", ["bytetrack", "ocsort"])
def test_a_tracker_of_simulated_detections_is_refused_before_any_work(tmp_path, capsys, tracker):
    """Its detections come from the ground truth, which no knob changes: every group had read
    +0.0 (ByteTrack 88.3 on every variant of seq8), as if the difficulty cost it nothing."""
    code = main(["difficulty", "--only", "seq9", "--trackers", "ncc", tracker,
                 "--out", str(tmp_path)])  # fmt: skip
    err = capsys.readouterr().err
    assert code == 2 and f"{tracker!r} tracks detections simulated from the ground truth" in err
    assert not any(tmp_path.iterdir())  # nothing generated


def test_a_cut_run_says_so_in_the_attribution(tmp_path, monkeypatch):
    """attribution.md and .json of a --frames run say they cover the first frames (table.md
    did; the attribution read as the whole sequences')."""
    import crowdsim.lab.experiments as experiments

    monkeypatch.setattr(experiments, "run_table", lambda *a, **k: None)
    doc = attribute("ucf9", tmp_path, only=["seq9"], trackers=["ncc"], groups=["shake"],
                    frames=15, log=lambda m: None)  # fmt: skip
    assert doc["frames"] == 15
    from crowdsim.lab.difficulty import attribution_table

    doc["sequences"] = {"seq9": {"ncc": {"calibrated": 90.0, "uncalibrated": 95.0,
                                         "regained": {"shake": 1.5}}}}  # fmt: skip
    head = attribution_table(doc).splitlines()[0]
    assert head == ("# Difficulty attribution on ucf9, first 15 frames of each sequence "
                    "(acc@15 %, and points regained)")  # fmt: skip
    whole = attribution_table({**doc, "frames": None}).splitlines()[0]
    assert whole == "# Difficulty attribution on ucf9 (acc@15 %, and points regained)"
