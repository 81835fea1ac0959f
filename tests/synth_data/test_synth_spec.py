"""Spec files: schema validation with errors naming file, field and value; shipped suites."""

from __future__ import annotations

import re

import pytest

from synth_data.spec import load_spec, spec_from_dict
from synth_data.suites import suite_specs

GOOD = """
name = "tiny"
seed = 4
frames = 10
fps = 25.0

[scenario]
name = "crossing"
n_agents = 10
density = 1.0

[camera]
tilt_deg = 10.0

[appearance]
template_px = 8
noise_sigma = 2.0

[calibration]
paper_ncc_15px = 33.0
"""


def write(tmp_path, text, name="s.toml"):
    p = tmp_path / name
    p.write_text(text)
    return p


def test_good_toml_and_equivalent_yaml(tmp_path):
    spec = load_spec(write(tmp_path, GOOD))
    assert (spec.name, spec.seed, spec.frames, spec.fps) == ("tiny", 4, 10, 25.0)
    assert spec.scenario == {"name": "crossing", "n_agents": 10, "density": 1.0}
    assert spec.appearance.template_px == 8 and spec.camera["tilt_deg"] == 10.0
    yaml_text = (
        "name: tiny\nseed: 4\nframes: 10\nfps: 25.0\n"
        "scenario: {name: crossing, n_agents: 10, density: 1.0}\n"
        "camera: {tilt_deg: 10.0}\nappearance: {template_px: 8, noise_sigma: 2.0}\n"
    )
    assert load_spec(write(tmp_path, yaml_text, "s.yaml")).digest() == spec.digest()


def test_digest_ignores_calibration_but_not_knobs(tmp_path):
    spec = load_spec(write(tmp_path, GOOD))
    other = load_spec(write(tmp_path, GOOD.replace("33.0", "40.0"), "b.toml"))
    assert other.digest() == spec.digest()
    noisier = load_spec(
        write(tmp_path, GOOD.replace("noise_sigma = 2.0", "noise_sigma = 5.0"), "c.toml")
    )
    assert noisier.digest() != spec.digest()
    assert spec.truncated(3).frames == 3 and spec.truncated(100).frames == 10
    assert spec.truncated(3).digest() != spec.digest()


@pytest.mark.parametrize(
    "old, new, field, value",
    [
        ("seed = 4", "seed = -1", "seed", "-1"),
        ("seed = 4", 'seed = "four"', "seed", "'four'"),
        ("frames = 10", "frames = 0", "frames", "0"),
        ('name = "tiny"', 'name = "a/b"', "name", "'a/b'"),
        ("tilt_deg = 10.0", "tilt_deg = 75.0", "camera.tilt_deg", "75"),
        ("tilt_deg = 10.0", "tlit_deg = 10.0", "camera.tlit_deg", "did you mean 'tilt_deg'"),
        ("template_px = 8", "template_px = 2", "appearance.template_px", "2"),
        ("template_px = 8", 'template_px = "big"', "appearance.template_px", "'big'"),
        ("noise_sigma = 2.0", "noise_sigma = 500.0", "appearance.noise_sigma", "500.0"),
        ('name = "crossing"', 'name = "disco"', "scenario", "'disco'"),
        ("n_agents = 10", "n_agents = 0", "n_agents", "0"),
        ("density = 1.0", "densty = 1.0", "scenario", "densty"),
        ("fps = 25.0", "fps = 25.0\ncolour = 1", "colour", ""),
    ],
)
def test_bad_fields_name_file_field_and_value(tmp_path, old, new, field, value):
    path = write(tmp_path, GOOD.replace(old, new, 1), "bad_spec.toml")
    with pytest.raises(ValueError) as info:
        load_spec(path)
    msg = str(info.value)
    assert msg.startswith(str(path)), msg
    assert field in msg and value in msg, msg


def test_missing_fields_and_syntax_errors(tmp_path):
    with pytest.raises(ValueError, match=r"missing required field 'seed'"):
        load_spec(write(tmp_path, GOOD.replace("seed = 4", "")))
    with pytest.raises(ValueError, match=r"missing required field 'scenario.name'"):
        load_spec(write(tmp_path, GOOD.replace('name = "crossing"', "")))
    with pytest.raises(ValueError, match=r"s\.toml: invalid TOML"):
        load_spec(write(tmp_path, GOOD + "\n[camera\n"))
    with pytest.raises(ValueError, match=r"s\.yaml: invalid YAML"):
        load_spec(write(tmp_path, "name: [unclosed\n", "s.yaml"))
    with pytest.raises(ValueError, match="no such spec file"):
        load_spec(tmp_path / "nope.toml")
    with pytest.raises(ValueError, match=r"must end in \.toml, \.yaml or \.yml"):
        load_spec(write(tmp_path, GOOD, "s.json"))


UCF9 = {  # SPEC §4: frames / people / template px
    1: (840, 152, 14),
    2: (134, 235, 16),
    3: (144, 175, 14),
    4: (492, 747, 16),
    5: (464, 171, 8),
    6: (133, 600, 10),
    7: (494, 73, 10),
    8: (126, 58, 10),
    9: (249, 57, 10),
}
PAPER_NCC = [49, 85, 58, 52, 33, 52, 50, 86, 33]


def test_ucf9_matches_the_spec_table():
    specs = suite_specs("ucf9")
    assert [s.name for s in specs] == [f"seq{i}" for i in range(1, 10)]
    for i, spec in enumerate(specs, 1):
        frames, people, tpl = UCF9[i]
        assert (spec.frames, spec.scenario["n_agents"], spec.appearance.template_px) == (
            frames,
            people,
            tpl,
        )
        assert spec.calibration["paper_ncc_15px"] == PAPER_NCC[i - 1]
    kinds = [s.scenario["name"] for s in specs]
    assert kinds == [
        "commuters",
        "circulation",
        "marathon",
        "marathon",
        "marathon",
        "marathon",
        "station",
        "station",
        "crossing",
    ]
    assert specs[6].camera["tilt_deg"] > 0
    assert len({s.seed for s in specs}) == 9


def test_other_suites_and_only():
    gal = suite_specs("galleria")
    assert [s.name for s in gal] == ["galleria1", "galleria2"]
    assert all(s.frames == 2000 and 150 <= s.scenario["n_agents"] <= 250 for s in gal)
    stress = suite_specs("stress")
    assert [s.scenario["n_agents"] for s in stress] == [1000, 10000, 50000]
    assert [s.name for s in suite_specs("ucf9", ["seq9", "seq2"])] == ["seq2", "seq9"]
    with pytest.raises(ValueError, match=re.escape("--only: no sequence 'seq10'")):
        suite_specs("ucf9", ["seq10"])
    with pytest.raises(ValueError, match="--suite must be one of"):
        suite_specs("nope")


def test_the_digest_covers_everything_that_changes_the_output():
    """Every spec field that shapes the sequence changes the digest (a stale folder is then
    never taken for a finished one); the calibration record, description and source do not."""
    import dataclasses

    from crowdsim import knobs
    from crowdsim.events import Event
    from synth_data.spec import CAMERA_FIELDS, OUTPUT_FIELDS, SequenceSpec, spec_from_dict

    base = load_spec_text(GOOD)
    digest = base.digest()
    changed = {
        "name": "other",
        "seed": 5,
        "frames": 9,
        "fps": 30.0,
        "warmup_steps": 3,
        "scenario": {**base.scenario, "n_agents": 11},
        "camera": {**base.camera, "tilt_deg": 12.0},
        "appearance": dataclasses.replace(base.appearance, noise_sigma=4.0),
        "output": {"images": True, "video": True},
        "events": (Event("lighting", start=2, frames=3, magnitude=0.5),),
    }
    kept = {"calibration": {"paper_ncc_15px": 1.0}, "description": "notes", "source": "x.toml"}
    fields = {f.name for f in dataclasses.fields(SequenceSpec)}
    assert fields == set(changed) | set(kept), "a new spec field: say whether it shapes output"
    for name, value in changed.items():
        assert dataclasses.replace(base, **{name: value}).digest() != digest, name
    for name, value in kept.items():
        assert dataclasses.replace(base, **{name: value}).digest() == digest, name
    for k in knobs.KNOBS:  # every rendering knob, appearance and camera alike
        other = _another_value(k)
        if k.section == "appearance":
            spec = dataclasses.replace(
                base, appearance=dataclasses.replace(base.appearance, **{k.name: other})
            )
        else:
            spec = spec_from_dict({**base.to_dict(), "camera": {**base.camera, k.name: other}})
        assert spec.digest() != digest, k.name
    # every camera field (fitted size and scale included) and every output switch, each given
    # a valid value of its own: a field the digest drops would let a stale folder pass
    camera = {
        "px_per_m": 20.0,
        "width": 100,
        "height": 80,
        "center": [1.0, 2.0],
        "tilt_deg": 12.0,
        "distance_m": 50.0,
        "jitter_px": 1.0,
        "jitter_frames": 5.0,
        "drift_px": 4.0,
        "rotate_deg": 1.0,
        "zoom": 0.02,
        "drone_frames": 90.0,
        "max_width": 500,
        "max_height": 400,
        "margin_m": 3.0,
        "ground_margin_px": 9,
    }
    assert set(camera) == set(CAMERA_FIELDS), "a new camera field: give it a value here"
    output = {"video": {"video": True}, "images": {"images": False, "video": True}}
    assert set(output) == set(OUTPUT_FIELDS)
    scenario = {"n_agents": {"n_agents": 11}, "density": {"density": 1.5}}
    camera = {key: {key: value} for key, value in camera.items()}
    camera["width"] = camera["height"] = {"width": 100, "height": 80}  # one needs the other
    for section, values in (("camera", camera), ("output", output), ("scenario", scenario)):
        for key, change in values.items():
            data = base.to_dict()
            data[section] = {**data[section], **change}
            assert spec_from_dict(data).digest() != digest, f"{section}.{key}"


def _another_value(k):
    if k.kind == "choice":
        return next(c for c in k.choices if c != k.default)
    if k.kind == "bool":
        return not k.default
    if k.kind == "bgr":
        return tuple(min(255, c + 1) for c in k.default)
    from crowdsim.appearance_model import AppearanceParams

    step = 1 if k.integer else max(0.01, k.off_below)
    for v in (k.default + step, k.default * 2, k.default - step):
        try:
            k.check(k.section, v)
            if k.section == "appearance":
                AppearanceParams(**{k.name: v})  # cross-field rules (subpixel divides 8)
        except ValueError:
            continue
        return v
    raise AssertionError(f"no other valid value for {k.name}")


def load_spec_text(text):
    import tempfile
    from pathlib import Path

    with tempfile.TemporaryDirectory() as d:
        return load_spec(write(Path(d), text))


def _spec(**over):
    data = {"name": "tiny", "seed": 0, "frames": 5, "scenario": {"name": "crossing", "n_agents": 4}}
    data.update(over)
    return spec_from_dict(data, "t.toml")


def test_spec_fps_range_includes_its_upper_end():
    """fps must be in [5, 1000]: both ends are accepted; above, 0 and 2 (a 0.5 s step, which
    the simulation refuses) are refused on load."""
    assert _spec(fps=1000.0).fps == 1000.0
    assert _spec(fps=5.0).fps == 5.0
    for bad in (1000.5, 0.0, 2.0):
        with pytest.raises(ValueError, match=r"t.toml: fps must be in \[5, 1000\]"):
            _spec(fps=bad)


def test_spec_camera_width_needs_height():
    """camera.width without camera.height is refused on load, naming the file."""
    with pytest.raises(ValueError, match=r"t.toml: camera.width needs camera.height"):
        _spec(camera={"width": 64})


def test_spec_camera_margin_range_includes_both_ends():
    """camera.margin_m must be in [0, 1000]: both ends are accepted, values outside refused."""
    assert _spec(camera={"margin_m": 0.0}).camera["margin_m"] == 0.0
    assert _spec(camera={"margin_m": 1000.0}).camera["margin_m"] == 1000.0
    for bad in (-0.5, 1000.5):
        with pytest.raises(ValueError, match=r"camera.margin_m must be in \[0, 1000\]"):
            _spec(camera={"margin_m": bad})


def test_a_suite_folder_reads_yaml_specs_too(tmp_path):
    """A folder with .toml, .yaml and .yml specs: all three are sequences (the .yaml one had
    been skipped in silence, and a folder of YAML alone had 'no spec files')."""
    from synth_data.suites import is_spec_suite, suite_specs

    body = "seed: 1\nframes: 5\nscenario:\n  name: crossing\n  n_agents: 6\n"
    (tmp_path / "a.toml").write_text(
        'name = "a"\nseed = 1\nframes = 5\n[scenario]\nname = "crossing"\nn_agents = 6\n'
    )
    (tmp_path / "b.yaml").write_text("name: b\n" + body)
    (tmp_path / "c.yml").write_text("name: c\n" + body)
    assert [s.name for s in suite_specs(tmp_path)] == ["a", "b", "c"]
    (tmp_path / "a.toml").unlink()
    assert is_spec_suite(tmp_path) and len(suite_specs(tmp_path)) == 2


@pytest.mark.parametrize(
    ("text", "message"),
    [
        (
            "name: t\nseed: 1\nframes: 5\nname: u\nscenario:\n  name: crossing\n",
            "invalid YAML: key 'name' is given twice (line 4, column 1)",
        ),
        (
            "name: t\nseed: 1\nframes: 5\nscenario:\n\tname: crossing\n",
            "found character '\\t' that cannot start any token (line 5, column 1)",
        ),
        (
            "name: manifest.json\nseed: 1\nframes: 5\nscenario:\n  name: crossing\n",
            "name 'manifest.json' is the name of a file the sequences' folder holds",
        ),
        (
            "name: v\nseed: 1\nframes: 5\nscenario:\n  name: crossing\n"
            "camera:\n  width: 201\n  height: 150\noutput:\n  video: true\n",
            "camera.width must be even for a video (output.video or appearance.video_kbps), "
            "got 201",
        ),
        (
            "name: v\nseed: 1\nframes: 5\nscenario:\n  name: crossing\n"
            "camera:\n  max_height: 81\nappearance:\n  video_kbps: 300.0\n",
            "camera.max_height must be even for a video",
        ),
    ],
)
def test_spec_mistakes_a_dataset_author_makes_are_named_when_read(tmp_path, text, message):
    path = tmp_path / "s.yaml"
    path.write_text(text)
    with pytest.raises(ValueError, match=re.escape(f"{path}: ") + ".*" + re.escape(message)):
        load_spec(path)


def test_yaml_merge_keys_are_read_and_duplicates_still_refused(tmp_path):
    """``<<: *anchor`` (YAML's merge key, which SafeLoader reads) had been refused as an
    unknown constructor by the duplicate-key check."""
    head = "name: m\nseed: 1\nframes: 5\nscenario:\n  name: crossing\n"
    path = tmp_path / "s.yaml"
    path.write_text(
        head + "events:\n  - &e {kind: noise, start: 1, frames: 2, magnitude: 3.0}\n"
        "  - {<<: *e, start: 3}\n"
    )
    spec = load_spec(path)
    assert [(e.kind, e.start, e.frames) for e in spec.events] == [("noise", 1, 2), ("noise", 3, 2)]
    path.write_text(head + "seed: 2\n")
    with pytest.raises(ValueError, match="seed"):
        load_spec(path)


def test_a_station_specs_digest_follows_its_route_layout():
    """Layout 1, what every station spec simulated before ``routes`` existed, keeps the
    digest of a spec without the key from then (its sequence is the same); a spec that takes
    the new default, layout 2, is a new sequence with a new digest."""
    import hashlib
    import json

    def spec(**routes):
        return _spec(scenario={"name": "station", "n_agents": 9, **routes})

    old = spec().to_dict()  # the digest as computed before the field: no special case
    for key in ("description", "calibration"):
        old.pop(key)
    before = hashlib.sha256(json.dumps(old, sort_keys=True).encode()).hexdigest()
    assert spec(routes=1).digest() == before
    assert spec().digest() == spec(routes=2).digest() != before
