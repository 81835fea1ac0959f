"""``crowdsim detect``, ``crowdsim track`` without hand-made points, ``crowdsim detector``:
the shipped head detector end to end on a rendered video, and every bad input."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from crowdsim.cli import main
from synth_data.births import read_points_csv
from synth_data.sequence import InMemorySequence
from synth_data.spec import spec_from_dict
from tracker.detect.matching import score_frame

pytest.importorskip("torch", reason="the head detector needs torch ([detect])")


def clip_spec(name: str = "clip", frames: int = 24):
    """A commuter scene (people keep entering) at the renderer's default look."""
    return spec_from_dict(
        {
            "name": name,
            "seed": 11,
            "frames": frames,
            "warmup_steps": 10,
            "scenario": {"name": "commuters", "n_agents": 60, "density": 0.8},
            "camera": {"max_width": 320, "max_height": 240},
            "appearance": {"template_px": 12},
        },
        source=f"{name}.toml",
    )


@pytest.fixture(scope="module")
def rendered(tmp_path_factory):
    """``(video, sequence)``: :func:`clip_spec` rendered in memory and written as an MP4."""
    seq = InMemorySequence.from_spec(clip_spec(), camera_output=True).materialize()
    frames = list(seq.frames())
    path = tmp_path_factory.mktemp("video") / "clip.mp4"
    h, w = frames[0].shape[:2]
    vw = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), 25.0, (w, h))
    for f in frames:
        vw.write(f)
    vw.release()
    return path, seq


def _error_line(capsys, command):
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"crowdsim {command}: error:"), err
    return err[0]


def test_detect_writes_the_people_of_frame_one_as_an_init_file(tmp_path, rendered, capsys):
    video, seq = rendered
    out = tmp_path / "points.csv"
    assert main(["detect", str(video), "--out", str(out), "--no-progress"]) == 0
    frames, ids, pts = read_points_csv(out)  # the file --init reads
    assert set(frames.tolist()) == {1} and len(np.unique(ids)) == len(ids)
    gt = seq.gt_points()[1][0]
    score = score_frame(pts, gt, 5.0)
    assert score.f1 >= 0.9, score  # the MP4 re-encoding on top of the sequence's own
    assert "frames/s" in capsys.readouterr().err


def test_heads_larger_than_the_detector_learnt_are_found_once(tmp_path, rendered):
    """The frame three times larger (36 px heads, the network learnt 8-16): with
    --template-size 36 the heads are found on the frame shrunk back to 12 px heads, at
    the people's places (at full size 54 people gave 156 points, 55 shrunk)."""
    video, seq = rendered
    frame = cv2.resize(next(iter(seq.frames())), None, fx=3, fy=3, interpolation=cv2.INTER_CUBIC)
    big = tmp_path / "big.mp4"
    vw = cv2.VideoWriter(str(big), cv2.VideoWriter_fourcc(*"mp4v"), 25.0, frame.shape[1::-1])
    vw.write(frame)
    vw.release()
    gt = seq.gt_points()[1][0]
    gt = gt[np.isfinite(gt).all(1)] * 3 + 1  # pixel centres: 3 x + 1 at 3x
    found = {}
    for size in (None, 36):
        out = tmp_path / f"p{size}.csv"
        flags = [] if size is None else ["--template-size", str(size)]
        assert main(["detect", str(big), "--out", str(out), "--no-progress", *flags]) == 0
        found[size] = read_points_csv(out)[2]
    assert len(found[None]) > 1.3 * len(gt)  # counted over and over at full size
    score = score_frame(found[36], gt, 15.0)
    assert score.f1 >= 0.85, score


def test_the_detector_is_told_a_head_size_never_a_body_width():
    """A MOT17 folder's template size is its body boxes' width: the detector keeps 12 px
    there (it had shrunk the frame by 12/40 and found 19 of 54 heads)."""
    from types import SimpleNamespace

    from crowdsim.commands.detect import head_size

    body = SimpleNamespace(info={}, box_type="body", template_size=40)
    head = SimpleNamespace(info={}, box_type="head", template_size=36)
    given = SimpleNamespace(info={"templateSize": "30"}, box_type="body", template_size=30)
    video = SimpleNamespace(template_size=12)
    assert [head_size(s, None) for s in (body, head, given, video)] == [12.0, 36.0, 30.0, 12.0]
    assert head_size(body, 20) == 20.0


def test_detect_all_frames_with_scores(tmp_path, rendered):
    video, seq = rendered
    out = tmp_path / "all.csv"
    assert (
        main(["detect", str(video), "--out", str(out), "--all", "--scores", "--no-progress"]) == 0
    )
    rows = np.loadtxt(out, delimiter=",", skiprows=1)
    assert set(rows[:, 0].astype(int)) == set(range(1, seq.length + 1))
    assert ((rows[:, 4] > 0) & (rows[:, 4] < 1)).all()


def test_track_a_video_with_no_points_starts_from_the_detector(tmp_path, rendered, capsys):
    video, _ = rendered
    out = tmp_path / "res.txt"
    args = ["track", str(video), "--out", str(out), "--no-progress", "--tracker", "ncc"]
    assert main([*args, "--births", "detect", "--detect-every", "4"]) == 0
    err = capsys.readouterr().err
    assert "heads in frame 1" in err and "born while tracking" in err
    born = int(err.split("head detector: ")[2].split(" people born")[0])
    rows = np.loadtxt(out, delimiter=",")
    n0 = int(err.split("head detector: ")[1].split(" heads")[0])
    assert len(np.unique(rows[:, 1])) == n0 + born and born > 0  # commuters keep arriving


@pytest.mark.parametrize(
    ("extra", "needle"),
    [
        (["--detector-threshold", "1.5"], "--detector-threshold"),
        (["--detector-threshold", "0"], "--detector-threshold"),
        (["--detect-every", "0"], "--detect-every"),
    ],
)
def test_track_refuses_bad_detector_flags(tmp_path, rendered, capsys, extra, needle):
    video, _ = rendered
    assert main(["track", str(video), "--out", str(tmp_path / "r.txt"), *extra]) == 2
    assert needle in _error_line(capsys, "track")


def test_damaged_or_foreign_weights_are_named(tmp_path, rendered, capsys):
    import torch

    video, _ = rendered
    bad = tmp_path / "bad.pt"
    bad.write_bytes(b"PK\x03\x04 truncated")
    foreign = tmp_path / "foreign.pt"
    torch.save({"weights": [1, 2]}, foreign)
    for path, why in ((bad, "not a readable weights file"), (foreign, "not a crowdsim head")):
        out = tmp_path / "p.csv"
        assert main(["detect", str(video), "--out", str(out), "--weights", str(path)]) == 2
        line = _error_line(capsys, "detect")
        assert str(path) in line and why in line
        assert not out.exists()
        args = ["track", str(video), "--out", str(tmp_path / "r.txt"), "--detector-weights"]
        assert main([*args, str(path)]) == 2
        assert why in _error_line(capsys, "track")


def test_detect_bad_inputs(tmp_path, rendered, capsys):
    video, _ = rendered
    out = str(tmp_path / "p.csv")
    assert main(["detect", str(video), "--out", out, "--threshold", "1"]) == 2
    assert "--threshold" in _error_line(capsys, "detect")
    assert main(["detect", str(video), "--out", str(tmp_path / "p.txt")]) == 2
    assert ".csv" in _error_line(capsys, "detect")
    empty = tmp_path / "empty.mp4"
    empty.write_bytes(b"")
    assert main(["detect", str(empty), "--out", out]) == 2
    assert "empty.mp4" in _error_line(capsys, "detect")
    small = tmp_path / "small.mp4"
    vw = cv2.VideoWriter(str(small), cv2.VideoWriter_fourcc(*"mp4v"), 25.0, (6, 6))
    for _ in range(3):
        vw.write(np.zeros((6, 6, 3), np.uint8))
    vw.release()
    if cv2.VideoCapture(str(small)).read()[0]:  # some builds cannot write a 6x6 video
        assert main(["detect", str(small), "--out", out]) == 2
        assert "smallest input" in _error_line(capsys, "detect")
    assert not (tmp_path / "p.csv").exists()


def test_detector_train_refuses_bad_flags(tmp_path, capsys):
    assert main(["detector", "train", "--out", str(tmp_path / "d"), "--workers", "999"]) == 2
    assert "--workers" in _error_line(capsys, "detector train")
    assert main(["detector", "train", "--out", str(tmp_path / "d"), "--iterations", "0"]) == 2
    assert "iterations" in _error_line(capsys, "detector train")
    assert not (tmp_path / "d").exists()


def test_track_a_folder_from_detections_and_evaluate(tmp_path, capsys):
    from synth_data.generate import build_sequence

    build_sequence(clip_spec("clipdir", frames=12), tmp_path)
    folder = tmp_path / "clipdir"
    out = tmp_path / "res.txt"
    args = ["track", str(folder), "--out", str(out), "--init", "detect", "--evaluate"]
    assert main([*args, "--no-progress", "--tracker", "ncc"]) == 0
    cap = capsys.readouterr()
    matched, present = (
        cap.err.split("heads in frame 1, ")[1].split(" people matched")[0].split(" of ")
    )
    assert int(matched) >= 0.9 * int(present)
    ids = np.unique(np.loadtxt(out, delimiter=",")[:, 1]).astype(int)
    gt_ids = np.unique(np.loadtxt(folder / "gt" / "gt.txt", delimiter=",")[:, 1]).astype(int)
    assert len(np.intersect1d(ids, gt_ids)) == int(matched)  # matched heads carry gt ids
    assert "acc@15" in cap.out


def test_bytetrack_on_a_video_is_fed_by_the_head_detector(tmp_path, rendered, capsys):
    pytest.importorskip("trackers", reason="needs the optional 'trackers' package ([detect])")
    video, seq = rendered
    out = tmp_path / "bt.txt"
    assert (
        main(["track", str(video), "--tracker", "bytetrack", "--out", str(out), "--no-progress"])
        == 0
    )
    rows = np.loadtxt(out, delimiter=",")
    people = int(np.isfinite(seq.gt_points()[1][-1]).all(1).sum())
    last = rows[rows[:, 0] == rows[:, 0].max()]
    assert len(last) >= 0.8 * people  # confirmed tracks on (nearly) every head in view
