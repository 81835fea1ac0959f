"""``crowdsim track`` and ``crowdsim evaluate`` end to end on tiny hand-built sequences."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from crowdsim.cli import main
from synth_data.mot import write_mot
from tracker.mot_io import tracks_to_mot_rows
from tracker.testing import make_scene


@pytest.fixture
def scene():
    return make_scene(
        [[20, 20], [90, 20], [100, 75], [25, 75]], [[2, 1], [-2, 1], [-2, 0], [1, -1]], n_frames=10
    )


@pytest.fixture
def seq(tmp_path, scene, scene_folder):
    return scene_folder(scene, tmp_path / "seq")


def _error_line(capsys, command):
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"crowdsim {command}: error:"), err
    return err[0]


@pytest.mark.parametrize("tracker", ["bqp", "ncc"])
def test_track_then_evaluate(tmp_path, seq, capsys, tracker):
    out = tmp_path / f"{tracker}.txt"
    video = tmp_path / "overlay.mp4"
    assert (
        main(
            [
                "track",
                str(seq),
                "--tracker",
                tracker,
                "--out",
                str(out),
                "--video",
                str(video),
                "--evaluate",
                "--no-progress",
            ]
        )
        == 0
    )
    captured = capsys.readouterr()
    assert "acc@15" in captured.out and "frames/s" in captured.err
    assert out.is_file() and video.stat().st_size > 0
    assert main(["evaluate", str(out), str(seq), "--json"]) == 0
    rep = json.loads(capsys.readouterr().out)
    for key in ("acc@5", "acc@15", "mota", "idf1", "hota"):
        assert key in rep
    assert rep["acc@5"] == 100.0 and rep["mota"] == pytest.approx(100.0)
    assert [c["T"] for c in rep["curve"]] == list(range(26))
    png = tmp_path / "curve.png"
    assert main(["evaluate", str(out), str(seq), "--plot", str(png)]) == 0
    assert "accuracy" in capsys.readouterr().out and png.is_file()


def test_a_crowd_too_large_for_trackeval_keeps_its_tracks_and_scores_acc_alone(
    tmp_path, seq, capsys, monkeypatch
):
    """TrackEval's dense tables past the memory limit (thousands of people; here a limit
    of 1 KiB): track --evaluate refuses the score after writing the tracks (they had been
    lost with an out-of-memory), and evaluate --metrics accuracy scores acc@T alone."""
    import tracker.metrics as metrics

    monkeypatch.setattr(metrics, "MEMORY_LIMIT_BYTES", 1024)
    out = tmp_path / "t.txt"
    argv = ["track", str(seq), "--tracker", "ncc", "--out", str(out), "--evaluate"]
    assert main([*argv, "--no-progress"]) == 2
    tracked, line = capsys.readouterr().err.strip().splitlines()
    assert tracked.startswith("ncc: 10 frames, 4 targets") and line.startswith("crowdsim track:")
    assert "MOTA, IDF1 and HOTA of 10 frames with 4 people and 4 tracks need about" in line
    assert "more than the 1.0 KiB limit" in line and line.endswith(f"written to {out})")
    assert out.is_file()
    assert main(["evaluate", str(out), str(seq)]) == 2
    assert "--metrics accuracy" in _error_line(capsys, "evaluate")
    assert main(["evaluate", str(out), str(seq), "--metrics", "accuracy", "--json"]) == 0
    rep = json.loads(capsys.readouterr().out)
    assert rep["acc@5"] == 100.0 and "mota" not in rep
    assert main(["evaluate", str(out), str(seq), "--metrics", "accuracy"]) == 0
    table = capsys.readouterr().out
    assert "100.0%" in table and "CLEAR/IDF1" not in table


def test_track_evaluate_maps_the_ids_of_a_points_csv_by_the_evidence(tmp_path, seq, scene, capsys):
    """--init CSV ids are the ground truth's numbers on other people (as a detector's 1..N
    are): scored by majority, as crowdsim evaluate scores the same file (it had scored them
    as the people of those numbers: acc@5 0.7 % against evaluate's 93 %)."""
    pts = tmp_path / "init.csv"
    rotated = np.roll(scene.ids, 1)
    pts.write_text(
        "frame,id,x,y\n"
        + "".join(
            f"1,{i},{x:g},{y:g}\n" for i, (x, y) in zip(rotated, scene.points[0], strict=True)
        )
    )
    out = tmp_path / "r.txt"
    argv = ["track", str(seq), "--tracker", "ncc", "--init", str(pts), "--out", str(out)]
    assert main([*argv, "--evaluate", "--no-progress"]) == 0
    tracked = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert main(["evaluate", str(out), str(seq), "--json"]) == 0
    rep = json.loads(capsys.readouterr().out)
    assert rep["id_mapping"] == "majority" and rep["acc@5"] == 100.0
    assert tracked["id_mapping"] == "majority" and tracked["acc@5"] == 100.0  # they agree


def test_evaluate_says_when_the_scores_would_mislead_and_scores_the_frames_asked(
    tmp_path, seq, scene, capsys
):
    """Results of the first 6 of 10 frames, ground truth on 2 frames, head boxes without
    boxType: each is named on stderr with the flag that scores it as meant."""
    from synth_data.mot import read_mot_file, write_mot

    out = tmp_path / "r.txt"
    argv = ["track", str(seq), "--tracker", "ncc", "--out", str(out), "--frames", "6"]
    assert main([*argv, "--no-progress"]) == 0
    capsys.readouterr()
    assert main(["evaluate", str(out), str(seq), "--json"]) == 0
    cut = capsys.readouterr()
    assert "the results end at frame 6 of 10; the people of frames 7-10 count as missed " in cut.err
    assert json.loads(cut.out)["acc@5"] == 60.0  # 6 of 10 frames
    assert main(["evaluate", str(out), str(seq), "--json", "--frames", "6"]) == 0
    first = capsys.readouterr()
    assert json.loads(first.out)["acc@5"] == 100.0 and "note" not in first.err
    gt = read_mot_file(seq / "gt" / "gt.txt")
    write_mot(seq / "gt" / "gt.txt", gt[np.isin(gt[:, 0], [3, 5])])  # two frames annotated
    info = seq / "seqinfo.ini"
    info.write_text(info.read_text().replace("boxType=head\n", ""))
    assert main(["evaluate", str(out), str(seq), "--json", "--frames", "6"]) == 0
    few = capsys.readouterr().err
    assert "ground truth on 2 of 6 frames: MOTA, IDF1 and HOTA count every tracked point" in few
    assert "seqinfo.ini gives no boxType" in few and "median height/width 1.00" in few
    info.write_text(info.read_text() + "boxType=head\n")
    assert (
        main(["evaluate", str(out), str(seq), "--json", "--frames", "6", "--annotated-frames"]) == 0
    )
    only = capsys.readouterr()
    rep = json.loads(only.out)
    assert rep["acc@5"] == 100.0 and rep["mota"] == pytest.approx(100.0) and "note" not in only.err
    assert main(["evaluate", str(out), str(seq), "--frames", "11"]) == 2
    assert "--frames must be in [1, 10]" in _error_line(capsys, "evaluate")
    assert main(["evaluate", str(out), str(seq), "--frames", "2", "--annotated-frames"]) == 2
    assert "no ground truth in the 2 frames scored" in _error_line(capsys, "evaluate")


def test_a_cut_video_is_tracked_to_its_end_with_a_note(tmp_path, scene, capsys):
    """The decoder stops before the header's count: one note line, the frames it gave."""
    whole = tmp_path / "whole.avi"
    h, w = scene.frames[0].shape[:2]
    vw = cv2.VideoWriter(str(whole), cv2.VideoWriter_fourcc(*"MJPG"), 25.0, (w, h))
    if not vw.isOpened():
        pytest.skip("this OpenCV build cannot write MJPG")
    for f in scene.frames:
        vw.write(f)
    vw.release()
    cut = tmp_path / "cut.avi"
    cut.write_bytes(whole.read_bytes()[: int(whole.stat().st_size * 0.6)])
    pts = tmp_path / "init.csv"
    pts.write_text(
        "frame,id,x,y\n"
        + "".join(
            f"1,{i},{x:g},{y:g}\n" for i, (x, y) in zip(scene.ids, scene.points[0], strict=True)
        )
    )
    argv = [
        "track",
        str(cut),
        "--tracker",
        "ncc",
        "--init",
        str(pts),
        "--out",
        str(tmp_path / "r.txt"),
    ]
    assert main([*argv, "--no-progress"]) == 0
    err = capsys.readouterr().err.strip().splitlines()
    notes = [e for e in err if e.startswith("crowdsim track: note: ")]
    assert len(notes) == 1 and "the decoder gave" in notes[0] and "the header counts 10" in notes[0]


def test_track_video_with_points_csv(tmp_path, scene, capsys):
    video = tmp_path / "in.mp4"
    h, w = scene.frames[0].shape[:2]
    vw = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"mp4v"), 25.0, (w, h))
    for f in scene.frames:
        vw.write(f)
    vw.release()
    pts = tmp_path / "init.csv"
    pts.write_text(
        "frame,id,x,y\n"
        + "".join(
            f"1,{i},{x:g},{y:g}\n" for i, (x, y) in zip(scene.ids, scene.points[0], strict=True)
        )
    )
    out = tmp_path / "res.txt"
    assert (
        main(
            [
                "track",
                str(video),
                "--tracker",
                "ncc",
                "--init",
                str(pts),
                "--out",
                str(out),
                "--template-size",
                "8",
                "--no-progress",
            ]
        )
        == 0
    )
    rows = np.loadtxt(out, delimiter=",")
    assert rows.shape[1] == 10 and set(rows[:, 1].astype(int)) == set(scene.ids.tolist())


def test_track_bad_inputs(tmp_path, seq, capsys):
    out = tmp_path / "r.txt"
    assert main(["track", str(tmp_path / "nope"), "--out", str(out)]) == 2
    _error_line(capsys, "track")
    bad = tmp_path / "bad.csv"
    bad.write_text("frame,id,x,y\n1,999,5,5\n")
    assert main(["track", str(seq), "--init", str(bad), "--out", str(out)]) == 2
    assert "unknown" in _error_line(capsys, "track")
    bad.write_text("frame,id,x,y\n1,1,5000,5\n")
    assert main(["track", str(seq), "--init", str(bad), "--out", str(out), "--no-progress"]) == 2
    assert "outside" in _error_line(capsys, "track")
    (tmp_path / "video.mp4").write_bytes(b"not a video")
    pts = tmp_path / "p.csv"
    pts.write_text("id,x,y\n1,5,5\n")
    assert main(["track", str(tmp_path / "video.mp4"), "--init", str(pts), "--out", str(out)]) == 2
    assert "video" in _error_line(capsys, "track")
    for threads in ("0", "100000"):
        assert main(["track", str(seq), "--out", str(out), "--threads", threads]) == 2
        assert "--threads must be an integer in [1, " in _error_line(capsys, "track")
    assert not out.exists()


def test_detector_flags_no_detector_uses_are_said_to_be_unused(tmp_path, seq, capsys):
    """A folder tracked from its own rows runs no head detector: the detector's flags are
    still checked (a missing weights file is refused) and the run says they went unused."""
    out = tmp_path / "r.txt"
    base = ["track", str(seq), "--tracker", "ncc", "--no-progress", "--out", str(out)]
    assert main([*base, "--detector-weights", str(tmp_path / "none.pt")]) == 2
    assert "--detector-weights" in _error_line(capsys, "track") and not out.exists()
    weights = tmp_path / "w.pt"
    weights.write_bytes(b"never read")
    assert main([*base, "--detector-weights", str(weights), "--detector-threshold", "0.4"]) == 0
    note = capsys.readouterr().err.splitlines()[0]
    assert note.startswith("note: --detector-weights and --detector-threshold unused")
    assert main([*base, "--overwrite"]) == 0
    assert "unused" not in capsys.readouterr().err


def test_evaluate_bad_inputs(tmp_path, seq, scene, capsys):
    res = tmp_path / "r.txt"
    res.write_text("1,1,10,10,8,8,1,-1,-1,-1\n1,1,oops,10,8,8,1,-1,-1,-1\n")
    assert main(["evaluate", str(res), str(seq)]) == 2
    assert "non-numeric" in _error_line(capsys, "evaluate")
    # results with their own ids (a tracking-by-detection tracker) are scored, not refused:
    # MOTA/IDF1/HOTA need no correspondence, acc@T maps each track to the person it follows
    rows = tracks_to_mot_rows(scene.ids + 100, scene.points, 8)
    write_mot(res, rows)
    assert main(["evaluate", str(res), str(seq), "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["mota"] == report["idf1"] == report["acc@15"] == 100.0
    assert report["id_mapping"] == "majority"
    rows = tracks_to_mot_rows(scene.ids, scene.points * 4, 8)  # tracks of a 4x larger video
    write_mot(res, rows)
    assert main(["evaluate", str(res), str(seq)]) == 2
    assert "mismatched frame sizes" in _error_line(capsys, "evaluate")
    rows = tracks_to_mot_rows(scene.ids, np.concatenate([scene.points, scene.points]), 8)
    write_mot(res, rows)
    assert main(["evaluate", str(res), str(seq)]) == 2
    assert "outside the sequence" in _error_line(capsys, "evaluate")
    assert main(["evaluate", str(tmp_path / "missing.txt"), str(seq)]) == 2
    _error_line(capsys, "evaluate")
    assert main(["evaluate", str(res), str(tmp_path)]) == 2
    _error_line(capsys, "evaluate")


def test_an_empty_results_file_scores_zero_and_says_so(tmp_path, seq, capsys):
    """A tracker that found no one is a valid result, but its 0 is never silent."""
    res = tmp_path / "empty.txt"
    res.write_text("")
    assert main(["evaluate", str(res), str(seq), "--json"]) == 0
    out = capsys.readouterr()
    assert json.loads(out.out)["acc@15"] == 0.0
    assert f"note: {res} has no result rows; every score is 0" in out.err
    assert main(["evaluate", str(res), str(seq)]) == 0
    assert "the results hold no track" in capsys.readouterr().out


def test_demo_frames_bound_is_the_embedded_sequences_length():
    import tomllib

    from crowdsim.commands.demo import DEMO_FRAMES, DEMO_SPEC

    assert tomllib.loads(DEMO_SPEC)["frames"] == DEMO_FRAMES


def test_demo_writes_table_curve_and_overlay(tmp_path, capsys):
    out = tmp_path / "demo"
    assert main(["demo", "--out", str(out), "--frames", "6", "--no-progress"]) == 0
    text = capsys.readouterr().out
    assert "acc@15" in text and "BQP" in text and "NCC" in text
    for name in ("accuracy_curve.png", "overlay_bqp.mp4", "results_bqp.txt", "results_ncc.txt"):
        assert (out / name).stat().st_size > 0
    summary = json.loads((out / "summary.json").read_text())
    assert set(summary["results"]) == {"BQP", "BQP-NCC", "PNMC", "NCC", "mean-shift", "ByteTrack"}
    # nothing re-entered the CLI: one simulate table, one generation, one tracking table
    assert text.count("scenario  ") == 1 and text.count("method") == 1
    assert summary["results"]["BQP"]["acc@15"] >= 90.0


def test_track_params_follow_the_files_tracker_only_when_none_is_given(tmp_path, seq, capsys):
    """A parameters file of ``ncc`` is NCC's: without --tracker it tracks with NCC (and says
    so), exactly like ``--tracker ncc --set ...``; with another --tracker it is refused."""
    params = tmp_path / "ncc.json"
    params.write_text(json.dumps({"tracker": "ncc", "params": {"search_factor": 3.0}}))
    followed, direct = tmp_path / "followed.txt", tmp_path / "direct.txt"
    argv = ["track", str(seq), "--no-progress"]
    assert main([*argv, "--params", str(params), "--out", str(followed)]) == 0
    err = capsys.readouterr().err
    assert f"tracking with ncc (the tracker the file names) with the parameters of {params}" in err
    assert main([*argv, "--tracker", "ncc", "--set", "search_factor=3", "--out", str(direct)]) == 0
    capsys.readouterr()
    assert followed.read_text() == direct.read_text()
    assert main([*argv, "--tracker", "ncc", "--params", str(params), "--out", str(direct)]) == 0
    capsys.readouterr()
    assert (
        main([*argv, "--tracker", "bqp", "--params", str(params), "--out", str(tmp_path / "x")])
        == 2
    )
    line = _error_line(capsys, "track")
    assert f"--params {params}: made for the 'ncc' tracker, but --tracker is 'bqp'" in line
    assert not (tmp_path / "x").exists()
    assert main([*argv, "--dense", "--set", "speedup=true", "--out", str(tmp_path / "x")]) == 2
    assert "--dense (no speed-up sampling) contradicts --set speedup=True" in _error_line(
        capsys, "track"
    )


def test_track_refuses_a_truncated_frame_without_checksums(tmp_path, seq, capsys):
    """A real MOT folder has no checksums.json: a JPEG cut short decodes in OpenCV with grey
    rows and no error, so it is named before tracking instead of being tracked silently."""
    import shutil

    jpg = tmp_path / "jpg"
    (jpg / "img1").mkdir(parents=True)
    shutil.copytree(seq / "gt", jpg / "gt")
    ini = (seq / "seqinfo.ini").read_text().replace("imExt=.png", "imExt=.jpg")
    (jpg / "seqinfo.ini").write_text(ini)
    for p in sorted((seq / "img1").glob("*.png")):
        cv2.imwrite(str(jpg / "img1" / f"{p.stem}.jpg"), cv2.imread(str(p)))
    out = tmp_path / "r.txt"
    assert main(["track", str(jpg), "--tracker", "ncc", "--no-progress", "--out", str(out)]) == 0
    capsys.readouterr()
    cut = jpg / "img1" / "000004.jpg"
    data = cut.read_bytes()
    cut.write_bytes(data[: len(data) * 2 // 3])
    assert cv2.imread(str(cut)) is not None  # OpenCV alone would track it
    out.unlink()
    assert main(["track", str(jpg), "--tracker", "ncc", "--no-progress", "--out", str(out)]) == 2
    assert f"{cut}: not a complete image" in _error_line(capsys, "track")
    assert not out.exists()


def test_a_rerun_replaces_its_own_results_and_only_overwrite_replaces_a_users(
    tmp_path, seq, capsys
):
    """``track --out`` replaces the file it wrote itself (the folder's ledger vouches for its
    digest), refuses one it did not write or that was edited since, unless ``--overwrite``."""
    from crowdsim.atomic import LEDGER

    out, video = tmp_path / "res.txt", tmp_path / "v.mp4"
    argv = ["track", str(seq), "--tracker", "ncc", "--no-progress", "--out", str(out)]
    assert main([*argv, "--frames", "3", "--video", str(video)]) == 0
    three = out.read_text()
    ledger = json.loads((tmp_path / LEDGER).read_text())
    assert set(ledger["files"]) == {"res.txt", "v.mp4"}
    assert main([*argv, "--frames", "5", "--video", str(video)]) == 0  # ours: replaced
    five = out.read_text()
    assert five != three and five.startswith(three.splitlines()[0])
    out.write_text(five + "1,99,0,0,12,12,1,-1,-1,-1\n")  # the user adds a row
    capsys.readouterr()
    assert main([*argv, "--frames", "3"]) == 2
    assert "cannot prove it wrote it" in _error_line(capsys, "track")
    assert out.read_text().endswith("1,99,0,0,12,12,1,-1,-1,-1\n")  # untouched
    assert main([*argv, "--frames", "3", "--overwrite"]) == 0
    assert out.read_text() == three
    ledger = json.loads((tmp_path / LEDGER).read_text())
    assert set(ledger["files"]) == {"res.txt", "v.mp4"}
    video.unlink()  # a file gone from the folder leaves the ledger at the next write
    assert main([*argv, "--frames", "3"]) == 0
    assert set(json.loads((tmp_path / LEDGER).read_text())["files"]) == {"res.txt"}


def test_evaluate_reads_body_box_results_as_body_box_ground_truth_is(tmp_path, seq, capsys):
    """A MOTChallenge-style folder (no boxType: body boxes, the head 0.08 of the height below
    the top) and results holding the very same tall boxes: 100 %, with a note (the results'
    box centres lay 0.42 box heights below the ground truth's heads: acc@15 0 %)."""
    from synth_data.mot import read_mot_file

    info = seq / "seqinfo.ini"
    info.write_text(info.read_text().replace("boxType=head\n", ""))
    gt = read_mot_file(seq / "gt" / "gt.txt")
    gt[:, 4], gt[:, 5] = 20.0, 60.0  # tall body boxes
    write_mot(seq / "gt" / "gt.txt", gt)
    res = tmp_path / "r.txt"
    write_mot(res, gt)
    assert main(["evaluate", str(res), str(seq), "--json"]) == 0
    got = capsys.readouterr()
    assert json.loads(got.out)["acc@15"] == 100.0
    assert "holds body boxes, as tiny's ground truth does" in got.err


def test_demo_help_names_the_files_it_writes(capsys):
    """``crowdsim demo --help`` said only "output folder": a user looking for the curve or the
    overlay had to read the source or the README."""
    from crowdsim.commands.demo import demo_files

    with pytest.raises(SystemExit):
        main(["demo", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    for name in ("accuracy_curve.png", "overlay_bqp.mp4", "summary.json", "sequences/"):
        assert name in text
    assert all(f.startswith("results_") or f in text for f in demo_files())


def test_track_video_ids_draws_the_tracks_ids(tmp_path, seq):
    """``--video-ids`` writes each track's id beside its box: the overlay differs from the
    one without."""
    base = ["track", str(seq), "--tracker", "ncc", "--frames", "3", "--no-progress"]
    videos = {}
    for name, extra in (("plain", []), ("ids", ["--video-ids"])):
        videos[name] = tmp_path / f"{name}.mp4"
        argv = [*base, "--out", str(tmp_path / f"{name}.txt"), "--video", str(videos[name])]
        assert main([*argv, *extra]) == 0
    frames = {}
    for name, path in videos.items():
        cap = cv2.VideoCapture(str(path))
        ok, frames[name] = cap.read()
        cap.release()
        assert ok
    diff = np.abs(frames["ids"].astype(int) - frames["plain"]).max(-1) > 60
    assert diff.sum() > 20  # the ids' strokes


@pytest.mark.parametrize("before", ["none", "ours"])
def test_a_file_put_at_out_while_tracking_is_kept(tmp_path, seq, capsys, monkeypatch, before):
    """``--out`` is checked before the work; a file the user puts there (or an edit of
    crowdsim's own) while the frames are tracked is theirs: kept, the run ends with one
    line and exit 2, and the ledger does not vouch for it."""
    import tracker.runner
    from crowdsim.atomic import LEDGER, sha256_file

    out = tmp_path / "res.txt"
    argv = ["track", str(seq), "--tracker", "ncc", "--frames", "3", "--no-progress"]
    argv += ["--out", str(out)]
    if before == "ours":
        assert main(argv) == 0
    real = tracker.runner.run_tracker

    def tracked_while_the_user_writes(*a, **k):
        run = real(*a, **k)
        out.write_text("my notes\n")
        return run

    monkeypatch.setattr(tracker.runner, "run_tracker", tracked_while_the_user_writes)
    capsys.readouterr()
    assert main(argv) == 2
    line = _error_line(capsys, "track")
    assert "res.txt" in line and "appeared there (or changed) while crowdsim ran" in line
    assert out.read_text() == "my notes\n"
    ledger = tmp_path / LEDGER
    listed = json.loads(ledger.read_text())["files"] if ledger.exists() else {}
    assert listed.get("res.txt") != sha256_file(out)
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".res")] == []
    monkeypatch.undo()
    assert main(argv) == 2  # and a rerun still cannot prove it wrote it
    assert "cannot prove it wrote it" in _error_line(capsys, "track")
