"""One sequence face: MOT folder, video file and in-memory sequences (SequenceSource)."""

from __future__ import annotations

import hashlib

import cv2
import numpy as np
import pytest

from synth_data.births import (
    DetectionBirths,
    births_from_ground_truth,
    births_from_points,
    read_points_csv,
)
from synth_data.generate import generate
from synth_data.mot import MotSequence, read_sequence
from synth_data.scene import Scene
from synth_data.sequence import (
    InMemorySequence,
    SequenceSource,
    VideoSequence,
    load_crowd,
    open_sequence,
    synthetic_crowd,
)
from synth_data.spec import spec_from_dict


def tiny(name="tiny", seed=4, frames=6):
    return spec_from_dict(
        {
            "name": name,
            "seed": seed,
            "frames": frames,
            "warmup_steps": 2,
            "scenario": {"name": "crossing", "n_agents": 12, "density": 1.0},
            "camera": {"px_per_m": 10.0, "jitter_px": 0.5},
            "appearance": {"template_px": 8, "noise_sigma": 3.0},
        },
        source=f"{name}.toml",
    )


def _gt(t=6, n=4, seed=0):
    rng = np.random.default_rng(seed)
    pts = rng.uniform(20, 200, (t, n, 2))
    pts[:2, 3] = np.nan  # id 4 enters at frame 2
    return np.arange(1, n + 1), pts


def _digest(seq):
    frames = hashlib.sha256()
    for f in seq.frames():
        frames.update(np.ascontiguousarray(f).tobytes())
    ids, pts = seq.gt_points()
    gt = hashlib.sha256(np.ascontiguousarray(pts).tobytes() + ids.astype(np.int64).tobytes())
    return frames.hexdigest(), gt.hexdigest()


# Digests of the frames and ground truth returned by the old
# ``crowdsim.bench.track.synthetic_crowd`` (commit 9f305d9, before the move), computed once
# with the function above on this platform.
OLD_SYNTHETIC_CROWD = [
    (
        dict(
            n=30, n_frames=5, seed=7, template_px=10, size=(160, 120), contrast=0.5, noise_sigma=4.0
        ),
        (
            "339dc6ea266d4b119ff882dbac9cbd95f382d0eafd7f7826440f6ede3b9b5a79",
            "0fc4608b69cb47f0e467c12726f9bccf707d4a41e13fe737336832e98ea7adb3",
        ),
    ),
    (
        dict(n=40, n_frames=4, seed=3, template_px=12, size=(200, 120), speed=2.0),
        (
            "089886d4e95e39e098699358638dfc32bdb3df5660b57bd52dc7e16f6bbc840d",
            "8972afa29c98625e9a5b15bec3e2611e4f16abc1e81bd00a6c2f7a361ae2b857",
        ),
    ),
]


@pytest.mark.parametrize("kwargs, digests", OLD_SYNTHETIC_CROWD)
def test_synthetic_crowd_gives_the_frames_and_gt_of_the_old_bench_function(kwargs, digests):
    seq = synthetic_crowd(**kwargs)
    assert _digest(seq) == digests
    assert isinstance(seq, SequenceSource)
    assert (seq.width, seq.height) == kwargs["size"] and seq.length == kwargs["n_frames"]
    assert seq.template_size == kwargs["template_px"]
    ids, pts = seq.gt_points()
    assert ids.tolist() == list(range(1, kwargs["n"] + 1))
    (ids0, pts0), later = seq.births()
    first = np.isfinite(pts).all(-1)
    np.testing.assert_array_equal(ids0, ids[first[0]])
    for t, (b_ids, b_pts) in later.items():
        assert not first[:t, np.isin(ids, b_ids)].any() and first[t, np.isin(ids, b_ids)].all()
        np.testing.assert_array_equal(b_pts, pts[t, np.isin(ids, b_ids)])


def test_in_memory_frames_equal_generated_frames_before_jpeg(tmp_path, monkeypatch):
    import crowdsim.render as render

    captured: list[np.ndarray] = []
    real = render.encode_jpeg

    def spy(frame, quality):
        captured.append(frame.copy())
        return real(frame, quality)

    monkeypatch.setattr(render, "encode_jpeg", spy)
    spec = tiny()
    generate([spec], tmp_path / "out", progress=False, log=lambda m: None)
    monkeypatch.setattr(render, "encode_jpeg", real)
    mem = InMemorySequence.from_spec(spec)
    frames = list(mem.frames())
    assert len(frames) == len(captured) == 6
    for a, b in zip(frames, captured, strict=True):
        np.testing.assert_array_equal(a, b)
    disk = read_sequence(tmp_path / "out" / "tiny")
    for key in ("name", "width", "height", "length", "template_size", "frame_rate"):
        assert getattr(mem, key) == getattr(disk, key), key
    ids, pts = mem.gt_points()
    d_ids, d_pts = disk.gt_points()
    np.testing.assert_array_equal(ids, d_ids)
    assert len(ids) > 0
    np.testing.assert_allclose(pts, d_pts, atol=1e-3)  # gt.txt keeps 3 decimals
    (m0, _), m_later = mem.births()
    (d0, _), d_later = disk.births()
    assert m0.tolist() == d0.tolist() and list(m_later) == list(d_later)
    # Drawn on demand, deterministic, random access; materialize keeps everything.
    again = mem.materialize()
    np.testing.assert_array_equal(list(again.frames())[3], frames[3])
    assert again.gt_points()[0].tolist() == ids.tolist()
    assert InMemorySequence.from_spec(spec, frames=3).length == 3


@pytest.mark.parametrize("kbps", [0.0, 300.0])
def test_camera_output_gives_the_frames_a_tracker_reads_from_the_generated_folder(tmp_path, kbps):
    from dataclasses import replace

    spec = tiny(frames=8)
    spec = replace(spec, appearance=replace(spec.appearance, jpeg_quality=60, video_kbps=kbps))
    generate([spec], tmp_path / "out", progress=False, log=lambda m: None)
    disk = np.stack(list(read_sequence(tmp_path / "out" / "tiny").frames()))
    seq = InMemorySequence.from_spec(spec, camera_output=True)
    mem = np.stack(list(seq.frames()))
    raw = np.stack(list(InMemorySequence.from_spec(spec).frames()))
    assert mem.shape == disk.shape == raw.shape
    # one code path (codec, then JPEG) and one decoder: the same JPEG bytes, codec or not
    np.testing.assert_array_equal(mem, disk)
    assert np.abs(mem.astype(float) - raw).mean() > 0.3  # the artefacts are there
    np.testing.assert_array_equal(np.stack(list(seq.materialize().frames())), mem)


def test_scene_frames_are_random_access_and_errors_name_the_index():
    scene = Scene.from_spec(tiny(frames=4))
    frames = list(scene.frames())
    np.testing.assert_array_equal(scene.frame(2), frames[2])
    with pytest.raises(ValueError, match=r"tiny: frame index must be in \[0, 3\], got 4"):
        scene.frame(4)


def test_in_memory_validation_names_the_field():
    f = [np.zeros((4, 5, 3), np.uint8)] * 2
    ok = dict(name="x", frame_rate=25.0, width=5, height=4, template_size=3)
    with pytest.raises(ValueError, match=r"'x'.frame_rate must be a finite number > 0, got 0"):
        InMemorySequence(**{**ok, "frame_rate": 0}, frames=f)
    with pytest.raises(ValueError, match="exactly one of frames and render"):
        InMemorySequence(**ok)
    with pytest.raises(ValueError, match="needs the length"):
        InMemorySequence(**ok, render=lambda t: f[0])
    with pytest.raises(ValueError, match=r"points must have shape \(2, 1, 2\)"):
        InMemorySequence(**ok, frames=f, ids=[1], points=np.zeros((3, 1, 2)))
    seq = InMemorySequence(**ok, frames=f)
    assert seq.gt_points()[1].shape == (2, 0, 2)
    with pytest.raises(ValueError, match="x: no ground truth"):
        seq.births()


def test_points_csv(tmp_path):
    p = tmp_path / "pts.csv"
    p.write_text("frame,id,x,y\n1,5,10,12\n1,6,30,40\n3,9,50,60\n")
    frames, ids, pts = read_points_csv(p)
    (i_ids, i_pts), births = births_from_points(frames, ids, pts)
    assert i_ids.tolist() == [5, 6] and list(births) == [2]
    assert births[2][0].tolist() == [9]
    p.write_text("id,x,y\n1,2,3\n")
    assert read_points_csv(p)[0].tolist() == [1]
    for text, msg in [
        ("", "empty"),
        ("a,b\n", "header"),
        ("id,x,y\n1,2\n", "columns"),
        ("id,x,y\n1,two,3\n", "non-numeric"),
        ("id,x,y\n1,2,3\n1,4,5\n", "once"),
    ]:
        p.write_text(text)
        with pytest.raises(ValueError, match=msg):
            read_points_csv(p)


def test_births_from_ground_truth():
    ids, gt = _gt()
    (i_ids, i_pts), births = births_from_ground_truth(ids, gt)
    assert i_ids.tolist() == [1, 2, 3]
    assert list(births) == [2] and births[2][0].tolist() == [4]
    np.testing.assert_allclose(births[2][1], gt[2, [3]])


@pytest.fixture(scope="module")
def crowd():
    return synthetic_crowd(6, 5, seed=1, template_px=8, size=(96, 64))


@pytest.fixture
def clip(tmp_path, crowd):
    """``crowd``'s frames as ``tmp_path/clip.mp4`` (mp4v, 20 frames/s)."""
    video = tmp_path / "clip.mp4"
    vw = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"mp4v"), 20.0, (96, 64))
    if not vw.isOpened():
        pytest.skip("this OpenCV build cannot write mp4v")
    for f in crowd.frames():
        vw.write(f)
    vw.release()
    return video


def test_video_sequence_and_open_sequence(tmp_path, clip):
    video = clip
    pts = tmp_path / "init.csv"
    pts.write_text("frame,id,x,y\n1,3,10,12\n1,4,30,40\n4,9,50,60\n")
    seq = open_sequence(video, init=pts)
    assert isinstance(seq, VideoSequence) and isinstance(seq, SequenceSource)
    assert (seq.name, seq.width, seq.height, seq.length) == ("clip", 96, 64, 5)
    assert seq.frame_rate == pytest.approx(20.0) and seq.template_size == 12
    frames = list(seq.frames())
    assert len(frames) == 5 and frames[0].shape == (64, 96, 3)
    ids, gt = seq.gt_points()
    assert ids.shape == (0,) and gt.shape == (5, 0, 2)
    (ids0, pts0), later = seq.births()
    assert ids0.tolist() == [3, 4] and list(later) == [3] and later[3][0].tolist() == [9]
    with pytest.raises(ValueError, match=r"clip\.mp4: a video has no ground truth.*--init"):
        VideoSequence(video).births()
    pts.write_text("frame,id,x,y\n9,1,10,12\n")
    with pytest.raises(ValueError, match=r"init\.csv: frame 9 is beyond the 5 frames"):
        open_sequence(video, init=pts).births()
    (tmp_path / "junk.mp4").write_bytes(b"not a video")
    with pytest.raises(ValueError, match=r"junk\.mp4: not a readable video file"):
        open_sequence(tmp_path / "junk.mp4")
    with pytest.raises(ValueError, match=r"nope: no such sequence folder or video file"):
        open_sequence(tmp_path / "nope")
    (tmp_path / "empty_dir").mkdir()
    with pytest.raises(ValueError, match=r"empty_dir: missing seqinfo\.ini"):
        open_sequence(tmp_path / "empty_dir")


def test_mot_folder_is_a_source_with_births_and_init(tmp_path):
    generate([tiny(frames=4)], tmp_path / "out", progress=False, log=lambda m: None)
    seq = open_sequence(tmp_path / "out" / "tiny")
    assert isinstance(seq, MotSequence) and isinstance(seq, SequenceSource)
    ids, pts = seq.gt_points()
    (ids0, pts0), later = seq.births()
    (e0, q0), e_later = births_from_ground_truth(ids, pts)
    assert ids0.tolist() == e0.tolist() and list(later) == list(e_later)
    np.testing.assert_allclose(pts0, q0)
    init = tmp_path / "init.csv"
    init.write_text(f"frame,id,x,y\n1,{ids[0]},5,5\n2,{ids[1]},6,6\n")
    (i0, _), i_later = open_sequence(tmp_path / "out" / "tiny", init=init).births()
    assert i0.tolist() == [ids[0]] and i_later[1][0].tolist() == [ids[1]]
    init.write_text("frame,id,x,y\n1,999,5,5\n")
    with pytest.raises(ValueError, match=r"init\.csv: ids \[999\] are unknown to the ground"):
        open_sequence(tmp_path / "out" / "tiny", init=init).births()
    mem = load_crowd(tmp_path / "out" / "tiny", max_frames=2)
    assert mem.length == 2 and mem.gt_points()[1].shape == (2, len(ids), 2)
    np.testing.assert_array_equal(next(mem.frames()), next(seq.frames()))


def test_ground_truth_births_skip_ids_that_are_never_present():
    """An id absent from every frame is neither an initial target nor a birth."""
    pts = np.full((3, 3, 2), np.nan)
    pts[:, 0] = [[1.0, 1.0], [2.0, 1.0], [3.0, 1.0]]
    pts[2, 2] = [9.0, 9.0]
    (init_ids, init_pts), births = births_from_ground_truth(np.array([4, 5, 6]), pts)
    assert init_ids.tolist() == [4]
    np.testing.assert_array_equal(init_pts, [[1.0, 1.0]])
    assert list(births) == [2]
    assert births[2][0].tolist() == [6]
    np.testing.assert_array_equal(births[2][1], [[9.0, 9.0]])


def test_detection_births_do_not_duplicate_a_scheduled_birth():
    """A head detected where a scheduled birth appears this frame is that birth, not a newcomer."""
    found = lambda frame: (np.array([[10.0, 10.0], [40.0, 12.0]]), np.ones(2))  # noqa: E731
    scheduled = {2: (np.array([5]), np.array([[41.0, 12.0]]))}
    births = DetectionBirths(found, every=2, radius=6.0, first_id=100, scheduled=scheduled)
    frame = np.zeros((32, 64, 3), np.uint8)
    ids, pts = births(2, frame, np.array([1]), np.array([[11.0, 9.0]]))
    assert ids.tolist() == [5] and births.born == 0
    np.testing.assert_array_equal(pts, [[41.0, 12.0]])


def test_an_in_memory_sequence_refuses_what_no_tracker_could_read():
    """Float frames, frames of another size, ids 1.5 or listed twice, a 1 px template and an
    init that is not (ids, points): refused by name where they had been kept (and truncated,
    or failed later inside the runner)."""
    import re

    frame = np.zeros((8, 10, 3), np.uint8)
    base = dict(name="s", frame_rate=25.0, width=10, height=8, template_size=4)
    for kw, message in [
        ({"frames": [frame.astype(np.float32)]}, "frame 0 must be (8, 10, 3) uint8"),
        ({"frames": [frame[:, :9]]}, "frame 0 must be (8, 10, 3) uint8"),
        ({"frames": [frame], "ids": [1.5], "points": [[[1.0, 1.0]]]}, "ids: 1.5 is not a whole"),
        ({"frames": [frame], "ids": [3, 3], "points": np.ones((1, 2, 2))}, "id 3 appears more"),
        ({"frames": [frame], "template_size": 1}, "template_size must be"),
        ({"frames": [frame], "init": 5}, "init must be (ids, points) of the first frame"),
    ]:
        with pytest.raises(ValueError, match=re.escape(message)):
            InMemorySequence(**{**base, **kw})
    assert "1 frames in memory" in repr(InMemorySequence(**base, frames=[frame]))


def test_a_video_whose_header_miscounts_its_frames_is_said_so(tmp_path, crowd):
    """A cut file (the header counts 30, the decoder gives fewer) warns as a DataNote;
    whole files give no note."""
    import warnings

    from crowdsim.checks import DataNote

    rng = np.random.default_rng(0)
    frames = [(rng.random((64, 96, 3)) * 255).astype(np.uint8) for _ in range(30)]
    for name in ("whole.avi", "whole.mkv"):
        vw = cv2.VideoWriter(str(tmp_path / name), cv2.VideoWriter_fourcc(*"MJPG"), 25.0, (96, 64))
        if not vw.isOpened():
            pytest.skip(f"this OpenCV build cannot write MJPG into {name}")
        for f in frames:
            vw.write(f)
        vw.release()
    data = (tmp_path / "whole.avi").read_bytes()
    (tmp_path / "cut.avi").write_bytes(data[: int(len(data) * 0.6)])
    seq = VideoSequence(tmp_path / "cut.avi")
    assert seq.length == 30  # what the header says
    with pytest.warns(
        DataNote, match=r"cut\.avi: the decoder gave (\d+) frames where the header counts 30"
    ):
        got = len(list(seq.frames()))
    assert 0 < got < 30
    mkv = VideoSequence(tmp_path / "whole.mkv")
    assert mkv.length == 30
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # whole files: no note
        assert len(list(mkv.frames())) == 30
        assert len(list(VideoSequence(tmp_path / "whole.avi").frames())) == 30


def test_a_video_template_size_is_checked_as_given(clip):
    for size in (0, 2.7, "12"):
        with pytest.raises(ValueError, match="template_size must be"):
            VideoSequence(clip, template_size=size)
    assert VideoSequence(clip, template_size=16.0).template_size == 16


@pytest.mark.parametrize("frames", [3.7, "3", -1])
def test_from_spec_frames_are_checked_as_given(frames):
    spec = {"name": "a", "seed": 1, "frames": 5, "scenario": {"name": "crossing", "n_agents": 6}}
    with pytest.raises(ValueError, match="InMemorySequence.from_spec.frames must be"):
        InMemorySequence.from_spec(spec, frames=frames)
