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


def test_detections_of_several_frames_are_no_init_file(tmp_path, rendered, capsys):
    video, _ = rendered
    one, three = tmp_path / "one.csv", tmp_path / "three.csv"
    assert main(["detect", str(video), "--out", str(one), "--no-progress"]) == 0
    assert main(["detect", str(video), "--out", str(three), "--frames", "3", "--no-progress"]) == 0
    assert one.read_text().startswith("frame,id,x,y\n")
    assert three.read_text().startswith("frame,detection,x,y\n")
    capsys.readouterr()
    args = ["track", str(video), "--tracker", "ncc", "--no-progress"]
    assert main([*args, "--out", str(tmp_path / "a.txt"), "--init", str(one)]) == 0
    capsys.readouterr()
    assert main([*args, "--out", str(tmp_path / "b.txt"), "--init", str(three)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "three.csv: per-frame detections" in err[0], err
    assert not (tmp_path / "b.txt").exists()


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
    # a pickle with objects a safe load refuses: never torch's hint to load it unsafely
    unsafe = tmp_path / "unsafe.pt"
    torch.save({"when": __import__("datetime").date(2020, 1, 1)}, unsafe)
    argv = ["detect", str(video), "--out", str(tmp_path / "q.csv"), "--weights", str(unsafe)]
    assert main(argv) == 2
    line = _error_line(capsys, "detect")
    assert "safe load refuses" in line and "weights_only=False" not in line
    # the shipped weights with a meta that is not a table
    from tracker.detect.inference import DEFAULT_WEIGHTS, WeightsError, load_weights

    blob = torch.load(DEFAULT_WEIGHTS, map_location="cpu", weights_only=True)
    blob["meta"] = [1, 2]
    odd = tmp_path / "odd.pt"
    torch.save(blob, odd)
    with pytest.raises(WeightsError, match="its 'meta' is not a table"):
        load_weights(odd)


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


def test_track_from_detections_on_a_body_box_folder_keeps_the_head_size(tmp_path, capsys):
    """A MOTChallenge-style folder (body boxes 40 px wide, no boxType, no templateSize): the
    detector keeps 12 px heads through track --init detect (the tracker's template, the body
    width, had overwritten it: 30 heads for 66 people)."""
    from synth_data.generate import build_sequence
    from synth_data.mot import read_mot_file, write_mot

    build_sequence(clip_spec("bodies", frames=3), tmp_path)
    folder = tmp_path / "bodies"
    info = folder / "seqinfo.ini"
    info.write_text(
        "".join(
            line
            for line in info.read_text().splitlines(keepends=True)
            if not line.startswith(("boxType", "templateSize"))
        )
    )
    gt = read_mot_file(folder / "gt" / "gt.txt")
    cx, cy = gt[:, 2] + gt[:, 4] / 2, gt[:, 3] + gt[:, 5] / 2
    gt[:, 4], gt[:, 5] = 40.0, 100.0  # body boxes whose head point is the same
    gt[:, 2], gt[:, 3] = cx - 20.0, cy - 0.08 * 100.0
    write_mot(folder / "gt" / "gt.txt", gt)
    (folder / "checksums.json").unlink()
    direct = tmp_path / "d.csv"
    assert main(["detect", str(folder), "--out", str(direct)]) == 0
    heads = len(read_points_csv(direct)[0])
    out = tmp_path / "r.txt"
    argv = ["track", str(folder), "--init", "detect", "--out", str(out), "--tracker", "ncc"]
    assert main([*argv, "--no-progress"]) == 0
    assert f"head detector: {heads} heads in frame 1" in capsys.readouterr().err


def test_a_header_that_counts_too_few_frames_is_said(tmp_path, rendered):
    """A reader that takes exactly the header's count (islice, as detect and track do) never
    resumed the generator, so the check after its loop never ran: now the note comes with
    the last counted frame."""
    import itertools
    import warnings

    from crowdsim.checks import DataNote
    from synth_data.sequence import VideoSequence

    video, _ = rendered
    seq = VideoSequence(video, template_size=12)
    seq.length = 5  # as a header that under-counts would say
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        got = list(itertools.islice(seq.frames(), seq.length))
    assert len(got) == 5
    assert any(issubclass(w.category, DataNote) and "more frames" in str(w.message) for w in caught)


def test_letterbox_bars_are_cropped_before_detection(rendered):
    """Flat black bars of a letterboxed video took the detector's recall to 0.06: the bars
    are cropped, the points shifted back."""
    from tracker.detect.inference import HeadDetector, content_box

    _, seq = rendered
    frame = next(iter(seq.frames()))
    h, w = frame.shape[:2]
    boxed = np.zeros((h + 80, w, 3), np.uint8)
    boxed[40 : 40 + h] = frame
    assert content_box(frame) == (0, h, 0, w)
    assert content_box(boxed) == (40, 40 + h, 0, w)
    det = HeadDetector()
    plain, _ = det.detect_points(frame)
    found, _ = det.detect_points(boxed)
    np.testing.assert_allclose(found, plain + [0, 40])


def test_a_damaged_checkpoint_is_named_before_the_training_data_is_rendered(tmp_path, capsys):
    """A checkpoint.pt that is not torch's (or not train's) had ended in an UnpicklingError
    traceback after minutes of rendering; it is read first and named."""
    import json
    from dataclasses import asdict, replace

    from crowdsim.lab.detector import MARKER, TrainConfig

    out = tmp_path / "tr"
    out.mkdir()  # as a stopped run of these settings left it
    config = replace(TrainConfig(), sequences=3, iterations=20, batch=2)
    (out / MARKER).write_text(json.dumps({"config": asdict(config)}))
    (out / "checkpoint.pt").write_text("x\n")
    argv = ["detector", "train", "--out", str(out), "--sequences", "3", "--iterations", "20"]
    assert main([*argv, "--batch", "2", "--no-progress"]) == 2
    assert "checkpoint.pt: not a readable checkpoint" in _error_line(capsys, "detector train")


def test_a_checkpoint_of_the_wrong_kind_is_named(tmp_path, capsys):
    """Right keys, wrong types (a history that is a number): named, not an AttributeError."""
    import json
    from dataclasses import asdict, replace

    import torch

    from crowdsim.lab.detector import MARKER, TrainConfig

    out = tmp_path / "tr"
    out.mkdir()
    config = replace(TrainConfig(), sequences=3, iterations=20, batch=2)
    (out / MARKER).write_text(json.dumps({"config": asdict(config)}))
    torch.save({"net": {}, "opt": {}, "iteration": 1, "history": 5}, out / "checkpoint.pt")
    argv = ["detector", "train", "--out", str(out), "--sequences", "3", "--iterations", "20"]
    assert main([*argv, "--batch", "2", "--no-progress"]) == 2
    assert "not a checkpoint of crowdsim detector train" in _error_line(capsys, "detector train")
