"""The knob table is the one home of every rendering knob: each row reaches the renderer's
validation, the calibration's difficulty scale, ``crowdsim difficulty``'s groups and the spec
docs, and nothing outside the table holds a knob of its own."""

from __future__ import annotations

import dataclasses
import math
import subprocess
import sys

import pytest

import synth_data.spec
from crowdsim import knobs
from crowdsim.appearance_model import AppearanceParams, Encoding
from crowdsim.camera import Camera
from crowdsim.knobs import knob
from crowdsim.lab import calibration
from crowdsim.lab.difficulty import DIFFICULTY_GROUPS, variant_specs
from synth_data.spec import CAMERA_FIELDS, spec_from_dict

APPEARANCE = list(knobs.knobs("appearance"))
CAMERA = list(knobs.knobs("camera"))
SCALED = knobs.scaled()


def _spec(**appearance):
    return spec_from_dict(
        {
            "name": "k",
            "seed": 1,
            "frames": 3,
            "scenario": {"name": "marathon", "n_agents": 5},
            "camera": {"px_per_m": 20.0},
            "appearance": appearance,
        }
    )


def test_every_appearance_field_is_a_row_with_the_same_default():
    fields = {f.name: f.default for f in dataclasses.fields(AppearanceParams)}
    assert set(fields) == {k.name for k in APPEARANCE}
    for k in APPEARANCE:
        assert fields[k.name] == k.default, k.name


def test_every_camera_knob_is_a_camera_field_and_a_spec_field():
    camera_fields = {f.name for f in dataclasses.fields(Camera)}
    for k in CAMERA:
        assert k.name in camera_fields and k.name in CAMERA_FIELDS, k.name


def _out_of_range(k: knobs.Knob) -> list:
    if k.kind == "choice":
        return ["no-such-choice"]
    if k.kind == "bool":
        return [1]
    if k.kind == "bgr":
        return [(k.hi + 1, 0, 0), (0, 0)]
    bad = [k.lo] if k.lo_open else [k.lo - 1]
    if math.isfinite(k.hi):
        bad.append(k.hi + 1)
    if k.off_below:
        bad.append(k.off_below / 1e9)
    return bad


@pytest.mark.parametrize("k", APPEARANCE + CAMERA, ids=lambda k: k.name)
def test_validation_reads_each_row(k):
    def make(value):
        if k.section == "appearance":
            return AppearanceParams(**{k.name: value})
        return Camera(px_per_m=10.0, width=64, height=64, **{k.name: value})

    make(k.default)
    for value in _out_of_range(k):
        with pytest.raises(ValueError, match=rf"{k.section}\.{k.name}"):
            make(value)


def test_a_bit_rate_that_would_round_to_nothing_is_refused():
    # 1e-9 kbit/s rounded to 0 bit/s, which x264 read as "no rate": better than 1 kbit/s
    with pytest.raises(ValueError, match=r"appearance.video_kbps must be 0 \(off\) or at least 1"):
        AppearanceParams(video_kbps=1e-9)
    with pytest.raises(ValueError, match="appearance.video_kbps"):
        Encoding(video_kbps=0.5)
    assert AppearanceParams(jpeg_quality=70, video_kbps=300.0).encoding == Encoding(
        jpeg_quality=70, video_kbps=300.0, video_codec="h264"
    )


def test_the_difficulty_scale_moves_every_scaled_knob_from_the_spec_to_its_hard_end():
    spec = _spec()
    easy = knobs.knob_values(spec, 0.0, 0.0)
    hard = knobs.knob_values(spec, 1.0, 1.0)
    assert set(easy) == set(hard) == {(k.section, k.name) for k in SCALED}
    for k in SCALED:
        assert hard[(k.section, k.name)] == pytest.approx(k.hard), k.name
        assert easy[(k.section, k.name)] == pytest.approx(
            k.default if k.on is not None else knobs.spec_value(spec, k)
        ), k.name
    only_scene = knobs.knob_values(spec, 1.0, 0.0)
    for k in SCALED:
        moved = only_scene[(k.section, k.name)] != easy[(k.section, k.name)]
        assert moved == (k.axis == "scene"), k.name


def test_calibration_records_and_reads_back_the_uncalibrated_value_of_every_scaled_knob(tmp_path):
    path = tmp_path / "k.toml"
    path.write_text(
        'name = "k"\nseed = 1\nframes = 3\n[scenario]\nname = "marathon"\nn_agents = 5\n'
        "[camera]\npx_per_m = 20.0\n[appearance]\nnoise_sigma = 5.0\n"
        "[calibration]\npaper_ncc_15px = 50.0\n"
    )
    spec = synth_data.spec.load_spec(path)
    values = knobs.knob_values(spec, 0.7, 0.7)
    calibration.write_calibration(
        path,
        {"anchor": "ncc11", "difficulty": 0.7, "score_15px": 50.0, "trials": 1, "values": values},
    )
    after = synth_data.spec.load_spec(path)
    base = calibration.uncalibrated_values(after)
    assert set(base) == {(k.section, k.name) for k in SCALED}
    assert base[("appearance", "noise_sigma")] == 5.0
    for (_section, name), value in values.items():
        assert knobs.spec_value(after, knobs.knob(name)) == pytest.approx(value), name


def test_difficulty_groups_cover_exactly_the_scaled_knobs():
    grouped = [n for names in DIFFICULTY_GROUPS.values() for n in names]
    assert sorted(grouped) == sorted(k.name for k in SCALED)
    spec = _spec()
    calibrated = knobs.apply_knobs(spec, knobs.knob_values(spec, 0.8, 0.8))
    record = {f"base_{s}_{n}": knobs.spec_value(spec, knobs.knob(n)) for s, n in
              knobs.knob_values(spec, 0, 0)}  # fmt: skip
    calibrated = dataclasses.replace(calibrated, calibration=record)
    variants = dict(variant_specs(calibrated))
    for group, names in DIFFICULTY_GROUPS.items():
        v = variants[f"-{group}"]
        for k in SCALED:
            got, cal = knobs.spec_value(v, k), knobs.spec_value(calibrated, k)
            want = knobs.spec_value(spec, k) if k.name in names else cal
            assert got == pytest.approx(want), (group, k.name)


def test_the_spec_docs_list_every_knob():
    helptext = subprocess.run(
        [sys.executable, "-m", "crowdsim", "generate", "--help"],
        capture_output=True,
        text=True,
        check=True,
    ).stdout
    for k in knobs.KNOBS:
        entry = f"{k.section}.{k.name} = "
        assert entry in synth_data.spec.__doc__, k.name
        assert entry in helptext, k.name


def test_the_static_profile_keeps_a_fixed_camera_and_realistic_image_formation():
    """Every camera knob has a sourced realistic end; on the static profile no knob goes past
    it, the camera never shakes or smears, and the scene knobs reach their hard ends."""
    spec = synth_data.spec.spec_from_dict(
        {"name": "s", "seed": 1, "frames": 3, "scenario": {"name": "marathon", "n_agents": 5}},
        source="s.toml",
    )
    at_one = knobs.knob_values(spec, 1.0, 1.0, "static")
    for k in SCALED:
        value = at_one[(k.section, k.name)]
        if k.axis == "camera":
            assert k.static is not None and k.source, k.name
            k.check(k.section, k.static)  # a realistic end is a valid value
            assert value == k.static, k.name
        else:
            assert value == k.hard, k.name
    assert at_one[("camera", "jitter_px")] == 0.0
    assert at_one[("appearance", "motion_blur_px")] == 0.0
    assert knobs.knob_values(spec, 1.0, 1.0) != at_one  # the hard profile goes further
    docs = " ".join(knobs.reference("appearance").split())
    assert "Realistic for a fixed camera: up to 10 (Liu et al." in docs
    with pytest.raises(ValueError, match="profile must be one of"):
        knobs.knob_values(spec, 0.5, 0.5, "shaky")


def test_a_log_scale_knob_switches_on_exactly_at_its_on_value():
    """Knob.at: below `on` a knob stays at its default; at `on` it takes `easy`."""
    k = knob("video_kbps")
    assert (k.on, k.easy, k.default) == (0.1, 4000.0, 0.0)
    assert k.at(0.1, 0.0) == 4000.0
    assert k.at(0.0999, 0.0) == 0.0
    assert k.at(1.0, 0.0) == 150.0


def test_a_spec_with_its_own_codec_starts_the_scale_at_its_own_bit_rate():
    """Difficulty 0 is the spec as written: a spec's own 1000 kbit/s had become no codec at
    all (0) and 3097 kbit/s at 0.2, easier than the spec; now 1000 -> 400 (static end) on the
    log scale, and a spec without a codec still switches it on at ``on``."""
    k = knob("video_kbps")
    assert k.at(0.0, 1000.0, "static") == 1000.0
    assert k.at(0.5, 1000.0, "static") == round(1000.0 * 0.4**0.5, 1) == 632.5
    assert k.at(1.0, 1000.0, "static") == 400.0
    assert k.at(1.0, 1000.0) == 150.0
    spec = _spec(video_kbps=1000.0)
    assert knobs.knob_values(spec, 0.0, 0.0, "static")[("appearance", "video_kbps")] == 1000.0
    assert [k.at(s, 0.0, "static") for s in (0.0, 0.1, 1.0)] == [0.0, 4000.0, 400.0]
