"""``crowdsim render``: CSV or .npz trajectories -> one MOTChallenge sequence."""

from __future__ import annotations

import numpy as np
import pytest

from crowdsim.trajectories import Trajectories
from synth_data.mot import read_sequence


def _main(argv):
    # no skip on ModuleNotFoundError: every command module exists, and a missing one (or a
    # broken import inside one) must fail these tests rather than turn them into skips
    from crowdsim import cli

    return cli.main(argv)


def _traj():
    t = np.arange(8)[:, None] * 0.1
    pos = np.stack(
        [
            np.column_stack([1.0 + t[:, 0], 1.0 + 0 * t[:, 0]]),
            np.column_stack([3.0 + 0 * t[:, 0], 2.0 + t[:, 0]]),
        ],
        axis=1,
    )
    return Trajectories(positions=pos, ids=np.array([0, 5]), dt=0.1)


def test_render_csv_with_defaults_fits_the_extent(tmp_path):
    csv = _traj().to_csv(tmp_path / "walk.csv")
    out = tmp_path / "seq"
    assert (
        _main(
            ["render", "--trajectories", str(csv), "--fps", "10", "--seed", "3", "--out", str(out)]
        )
        == 0
    )
    seq = read_sequence(out)
    assert seq.length == 8 and seq.frame_rate == 10.0 and seq.template_size == 12
    ids, pts = seq.gt_points()
    np.testing.assert_array_equal(ids, [1, 6])
    assert np.isfinite(pts).all()
    assert (pts[..., 0] > 0).all() and (pts[..., 0] < seq.width).all()
    assert seq.frame(1).shape == (seq.height, seq.width, 3)


def test_render_video_that_does_not_reach_the_disk_whole_publishes_nothing(
    tmp_path, capsys, dropping_video_writer
):
    """``--video`` (mp4v through OpenCV) on a disk that fills: the writer says nothing, the
    video is read back, and the run ends with one line and no sequence."""
    csv = _traj().to_csv(tmp_path / "walk.csv")
    out = tmp_path / "seq"
    argv = ["render", "--trajectories", str(csv), "--fps", "10", "--video", "--out", str(out)]
    assert _main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "the video was not written whole" in err[0], err
    assert ".crowdsim-tmp" not in err[0] and str(out) in err[0]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["walk.csv"]


def test_render_npz_with_size_and_scale(tmp_path):
    npz = _traj().save(tmp_path / "walk.npz")
    out = tmp_path / "seq"
    assert (
        _main(
            [
                "render",
                "--trajectories",
                str(npz),
                "--px-per-m",
                "20",
                "--size",
                "160x96",
                "--out",
                str(out),
            ]
        )
        == 0
    )
    seq = read_sequence(out)
    assert (seq.width, seq.height, seq.frame_rate) == (160, 96, 10.0)
    ids, pts = seq.gt_points()
    # 2 m apart in x at t=0 (x = 1 and 3) -> 40 px apart at 20 px/m.
    assert pts[0, 1, 0] - pts[0, 0, 0] == pytest.approx(40.0, abs=1e-2)
    # An existing folder is not overwritten without --overwrite.
    assert _main(["render", "--trajectories", str(npz), "--out", str(out)]) == 2
    assert _main(["render", "--trajectories", str(npz), "--overwrite", "--out", str(out)]) == 0


@pytest.mark.parametrize(
    "extra, message",
    [
        ([], "--fps is required for CSV"),
        (["--fps", "0"], "--fps must be in (0, 1000], got 0"),
        (["--fps", "10", "--px-per-m", "-2"], "--px-per-m must be in [0.001, 10000], got -2"),
    ],
)
def test_render_bad_flags_exit_2_with_one_line(tmp_path, capsys, extra, message):
    csv = _traj().to_csv(tmp_path / "walk.csv")
    assert (
        _main(["render", "--trajectories", str(csv), *extra, "--out", str(tmp_path / "seq")]) == 2
    )
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and message in err[0]


def test_render_malformed_csv_names_the_line(tmp_path, capsys):
    bad = tmp_path / "bad.csv"
    bad.write_text("frame,id,x,y\n0,1,0.5,0.5\n1,1,abc,0.5\n")
    assert (
        _main(["render", "--trajectories", str(bad), "--fps", "10", "--out", str(tmp_path / "seq")])
        == 2
    )
    assert "bad.csv:3" in capsys.readouterr().err
    assert not (tmp_path / "seq").exists()


def _dead_pid() -> int:
    import subprocess
    import sys

    proc = subprocess.run(
        [sys.executable, "-c", "import os; print(os.getpid())"],
        capture_output=True,
        text=True,
        check=True,
    )
    return int(proc.stdout)


def test_overwrite_replaces_only_our_folders(tmp_path, capsys):
    csv = _traj().to_csv(tmp_path / "walk.csv")
    seq = tmp_path / "seq"
    argv = ["render", "--trajectories", str(csv), "--fps", "10", "--size", "64x48"]
    assert _main([*argv, "--out", str(seq)]) == 0
    first = (seq / "checksums.json").read_text()
    # A sequence of ours is replaced (different seed -> different frames).
    assert _main([*argv, "--seed", "5", "--overwrite", "--out", str(seq)]) == 0
    assert (seq / "checksums.json").read_text() != first
    # ... but not once a file of the user's sits inside it.
    (seq / "notes.txt").write_text("mine")
    assert _main([*argv, "--overwrite", "--out", str(seq)]) == 2
    assert "notes.txt was not written by crowdsim" in capsys.readouterr().err
    assert (seq / "notes.txt").read_text() == "mine"
    # A suite folder (manifest.json + sequence folders) may be replaced.
    suite = tmp_path / "suite"
    suite.mkdir()
    (suite / "manifest.json").write_text('{"format": 1, "sequences": {}}')
    (seq / "notes.txt").unlink()
    seq.rename(suite / "seq")
    assert _main([*argv, "--overwrite", "--out", str(suite)]) == 0
    assert (suite / "seqinfo.ini").is_file() and not (suite / "manifest.json").exists()
    # A user folder, the input itself, or a folder holding the input: refused, kept.
    thesis = tmp_path / "thesis"
    thesis.mkdir()
    (thesis / "thesis.tex").write_text("\\chapter{One}")
    for out, needle in (
        (thesis, "has no checksums.json"),
        (csv, "would replace the input"),
        (tmp_path, "would replace the input"),
    ):
        capsys.readouterr()
        assert _main([*argv, "--overwrite", "--out", str(out)]) == 2
        assert needle in capsys.readouterr().err
    assert (thesis / "thesis.tex").read_text() == "\\chapter{One}"
    assert csv.read_text().startswith("frame,id,x,y")


def test_render_removes_a_killed_renders_tmp_folder_only(tmp_path, capsys):
    import json
    import socket

    from synth_data.writer import TMP_MARKER, TMP_PREFIX

    csv = _traj().to_csv(tmp_path / "walk.csv")
    pid = _dead_pid()
    stale = tmp_path / f"{TMP_PREFIX}seq-{pid}-0badf00d"
    (stale / "img1").mkdir(parents=True)
    (stale / "img1" / "000001.jpg").write_bytes(b"partial")
    (stale / TMP_MARKER).write_text(
        json.dumps({"pid": pid, "host": socket.gethostname(), "target": "seq", "created": 0.0})
    )
    lookalike = tmp_path / f"{TMP_PREFIX}notes-2024"  # no marker: the user's
    lookalike.mkdir()
    (lookalike / "thesis.txt").write_text("mine")
    assert (
        _main(
            [
                "render",
                "--trajectories",
                str(csv),
                "--fps",
                "10",
                "--size",
                "64x48",
                "--out",
                str(tmp_path / "seq"),
            ]
        )
        == 0
    )
    assert f"removed {stale}" in capsys.readouterr().err
    assert not stale.exists()
    assert (lookalike / "thesis.txt").read_text() == "mine"
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(["walk.csv", "seq", lookalike.name])


@pytest.mark.parametrize(
    "plant",
    [
        "suite/.notes",  # a hidden file beside the sequences of a suite folder
        "suite/seq/gt/my_labels.txt",  # anything a user put in gt/ ...
        "suite/seq/img1/000001_fixed.jpg",  # ... or img1/
        "suite/seq/.DS_Store",
    ],
)
def test_overwrite_keeps_every_user_file_in_a_suite_or_sequence(tmp_path, capsys, plant):
    csv = _traj().to_csv(tmp_path / "walk.csv")
    argv = ["render", "--trajectories", str(csv), "--fps", "10", "--size", "64x48"]
    suite = tmp_path / "suite"
    suite.mkdir()
    (suite / "manifest.json").write_text('{"format": 1, "sequences": {}}')
    assert _main([*argv, "--out", str(suite / "seq")]) == 0
    user = tmp_path / plant
    user.write_text("mine")
    for out in (suite, suite / "seq"):
        if user.parent == suite and out != suite:
            continue  # a file beside the sequence is not inside it
        capsys.readouterr()
        assert _main([*argv, "--overwrite", "--out", str(out)]) == 2
        assert f"{user} was not written by crowdsim" in capsys.readouterr().err
        assert user.read_text() == "mine"


def test_overwrite_refuses_a_sequence_whose_files_were_changed(tmp_path, capsys):
    csv = _traj().to_csv(tmp_path / "walk.csv")
    argv = ["render", "--trajectories", str(csv), "--fps", "10", "--size", "64x48"]
    seq = tmp_path / "seq"
    assert _main([*argv, "--out", str(seq)]) == 0
    gt = seq / "gt" / "gt.txt"
    gt.write_text(gt.read_text() + "1,99,1,1,12,12,1,1,1\n")  # a user's hand correction
    assert _main([*argv, "--overwrite", "--out", str(seq)]) == 2
    assert "gt.txt: damaged" in capsys.readouterr().err
    assert "1,99," in gt.read_text()


def test_generate_overwrite_keeps_a_user_file_inside_a_sequence(tmp_path, capsys):
    from crowdsim.cli import main

    spec = tmp_path / "s.toml"
    spec.write_text(
        'name = "s"\nseed = 1\nframes = 3\n[scenario]\nname = "marathon"\nn_agents = 40\n'
        "[camera]\nmax_width = 64\nmax_height = 48\n[appearance]\ntemplate_px = 8\n"
    )
    out = tmp_path / "out"
    gen = ["generate", "--spec", str(spec), "--out", str(out), "--workers", "1", "--no-progress"]
    assert main(gen) == 0
    (out / "s" / "gt" / "notes.txt").write_text("mine")
    spec.write_text(spec.read_text().replace("seed = 1", "seed = 2"))  # another spec
    assert main([*gen, "--overwrite"]) == 2
    assert "notes.txt was not written by crowdsim" in capsys.readouterr().err
    assert (out / "s" / "gt" / "notes.txt").read_text() == "mine"


def _render_argv(tmp_path, *extra):
    csv = _traj().to_csv(tmp_path / "walk.csv")
    return ["render", "--trajectories", str(csv), "--fps", "10", "--size", "64x48", *extra]


def test_ctrl_c_while_overwrite_swaps_the_folders_waits_for_a_whole_sequence(tmp_path, monkeypatch):
    """SIGINT arriving between the two renames of ``--overwrite`` (old aside, new in) is held
    until the name holds the new sequence; a failing second rename puts the old one back."""
    import os
    import shutil
    import signal

    from synth_data import writer
    from synth_data.mot import not_ours

    seq = tmp_path / "seq"
    assert _main(_render_argv(tmp_path, "--out", str(seq))) == 0
    real = os.replace

    def replace_then_ctrl_c(src, dst):
        real(src, dst)
        if os.path.basename(dst).startswith(writer.OLD_PREFIX):
            os.kill(os.getpid(), signal.SIGINT)  # a real Ctrl-C, right after the first rename

    def new_copy():  # a whole new sequence in a temporary folder, as write_sequence makes it
        tmp = writer.make_tmp_dir(seq)
        shutil.copytree(seq, tmp, dirs_exist_ok=True)
        return tmp

    monkeypatch.setattr(writer.os, "replace", replace_then_ctrl_c)
    handler = signal.signal(signal.SIGINT, signal.default_int_handler)  # pytest-xdist ignores it
    try:
        with pytest.raises(KeyboardInterrupt):
            writer.publish_tmp_dir(new_copy(), seq, overwrite=True)
    finally:
        signal.signal(signal.SIGINT, handler)
    assert not_ours(seq) is None and not (seq / writer.TMP_MARKER).exists()

    def second_fails(src, dst):
        if os.path.basename(src).startswith(writer.TMP_PREFIX):
            raise OSError(28, "No space left on device", dst)
        real(src, dst)

    before = sorted(p.relative_to(seq) for p in seq.rglob("*"))
    monkeypatch.setattr(writer.os, "replace", second_fails)
    with pytest.raises(OSError):
        writer.publish_tmp_dir(new_copy(), seq, overwrite=True)
    assert sorted(p.relative_to(seq) for p in seq.rglob("*")) == before
    assert not_ours(seq) is None


def test_a_sigterm_held_while_the_sequence_is_renamed_in_says_it_is_whole(
    tmp_path, capsys, monkeypatch
):
    """Seen by injection: a SIGTERM held while the finished sequence was renamed into place is
    raised once it has its name. The line said the unfinished temporary folder was removed
    (the sequence was whole, and the rerun then refused it as existing), and with
    ``--overwrite`` the old sequence was left beside it, renamed aside and hidden."""
    import os
    import signal

    from synth_data import writer
    from synth_data.mot import not_ours

    seq = tmp_path / "seq"
    real = os.replace

    def replace_then_sigterm(src, dst):
        real(src, dst)
        if os.path.basename(src).startswith(writer.TMP_PREFIX):
            os.kill(os.getpid(), signal.SIGTERM)  # a real one, held until the block ends

    monkeypatch.setattr(writer.os, "replace", replace_then_sigterm)
    for extra in ((), ("--overwrite",)):
        assert _main(_render_argv(tmp_path, *extra, "--out", str(seq))) == 143
        err = capsys.readouterr().err.strip().splitlines()
        assert err == [
            f"crowdsim render: interrupted by SIGTERM; the sequence was written whole first: {seq}"
        ]
        assert not_ours(seq) is None
        assert sorted(p.name for p in tmp_path.iterdir()) == ["seq", "walk.csv"]


def test_a_sequence_a_killed_overwrite_moved_aside_gets_its_name_back(tmp_path, capsys):
    """SIGKILL (which cannot be held) between the two renames leaves the old sequence under a
    hidden name: the next render puts it back; one killed after the swap leaves it beside
    the new one, and the next render deletes it. A look-alike of the user's is kept."""
    import shutil

    from synth_data.writer import OLD_PREFIX

    seq = tmp_path / "seq"
    assert _main(_render_argv(tmp_path, "--out", str(seq))) == 0
    gt = (seq / "gt" / "gt.txt").read_text()
    hidden = tmp_path / f"{OLD_PREFIX}seq-{_dead_pid()}-0badf00d"
    seq.rename(hidden)
    mine = tmp_path / f"{OLD_PREFIX}notes-{_dead_pid()}-12345678"  # no checksums: the user's
    mine.mkdir()
    (mine / "a.txt").write_text("mine")
    assert _main(_render_argv(tmp_path, "--out", str(seq))) == 2  # the old one is back
    assert "already exists" in capsys.readouterr().err
    assert (seq / "gt" / "gt.txt").read_text() == gt and not hidden.exists()
    shutil.copytree(seq, hidden)
    assert _main(_render_argv(tmp_path, "--out", str(seq), "--overwrite")) == 0
    assert not hidden.exists() and (mine / "a.txt").read_text() == "mine"


def test_a_marker_a_killed_render_left_in_its_published_sequence_is_crowdsims(tmp_path):
    import json
    import socket

    from synth_data.mot import not_ours
    from synth_data.writer import TMP_MARKER

    seq = tmp_path / "seq"
    assert _main(_render_argv(tmp_path, "--out", str(seq))) == 0
    marker = {"pid": _dead_pid(), "host": socket.gethostname(), "target": "seq", "created": 0}
    (seq / TMP_MARKER).write_text(json.dumps(marker) + "\n")
    assert not_ours(seq) is None
    (seq / TMP_MARKER).write_text("my notes\n")  # not a marker: a file of the user's
    assert "was not written by crowdsim" in not_ours(seq)
    (seq / TMP_MARKER).write_text(json.dumps(marker) + "\n")
    assert _main(_render_argv(tmp_path, "--out", str(seq), "--overwrite")) == 0
    assert not (seq / TMP_MARKER).exists()


def test_a_public_data_set_csv_reads_and_maps_back(tmp_path, capsys):
    """ETH/UCY-style: a byte-order mark, quoted names, tabs, frames every 10th, a negative id.
    Without --frame-step the stride is refused by name (people would blink in one frame of
    10); with it the frames are consecutive, and meta.json maps MOT frames and ids back to
    the file's."""
    import json

    csv = tmp_path / "eth.csv"
    rows = "0\t-3\t1.0\t1.0\n10\t-3\t1.5\t1.0\n10\t5\t3.0\t2.0\n20\t5\t3.2\t2.0\n20\t-3\t2.0\t1.0\n"
    csv.write_bytes(b"\xef\xbb\xbf" + ('"frame"\t"id"\t"x"\t"y"\n' + rows).encode())
    out = tmp_path / "seq"
    argv = ["render", "--trajectories", str(csv), "--fps", "2.5", "--out", str(out)]
    assert _main(argv) == 2
    assert "every frame number steps by 10" in capsys.readouterr().err and not out.exists()
    assert _main([*argv, "--frame-step", "10"]) == 0
    ids, pts = read_sequence(out).gt_points()
    assert pts.shape == (3, 2, 2) and np.isfinite(pts[:, 0]).all()  # id -3 in all 3 frames
    meta = json.loads((out / "meta.json").read_text())
    assert meta["csv_frame_of_mot_frame_1"] == 0 and meta["csv_frame_step"] == 10
    assert meta["csv_id_of_mot_id"] == {"1": -3, "2": 5}
    assert _main([*argv, "--frame-step", "3", "--overwrite"]) == 2
    assert "frame 10 is not a multiple of --frame-step 3" in capsys.readouterr().err


def test_render_video_with_odd_size_is_refused_before_any_work(tmp_path, capsys):
    """An odd --size with --video wrote a video.mp4 one column and one row smaller than
    img1/ and seqinfo.ini (OpenCV's MPEG-4 writer drops them in silence)."""
    csv = _traj().to_csv(tmp_path / "walk.csv")
    out = tmp_path / "seq"
    base = ["render", "--trajectories", str(csv), "--fps", "10", "--out", str(out)]
    assert _main([*base, "--size", "161x120", "--video"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["crowdsim render: error: --size must have even sides for --video, got 161x120"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["walk.csv"]
    assert _main([*base, "--size", "161x121"]) == 0  # images alone take any size
    assert read_sequence(out).width == 161


def test_a_sequence_another_render_published_meanwhile_is_refused_in_one_line(
    tmp_path, capsys, monkeypatch
):
    """Seen racing two ``render --out`` into one new folder: the one that finished second
    found the other's sequence at the name and ended with a garbled line (its own message
    wrapped as an ``OSError`` with ``[Errno None]`` and the path twice). It says in one line
    that the folder exists, exit 2, and the other's sequence is kept."""
    import shutil

    from synth_data import writer
    from synth_data.mot import not_ours

    seq, other = tmp_path / "seq", tmp_path / "other"
    assert _main(_render_argv(tmp_path, "--out", str(other))) == 0
    real = writer.publish_tmp_dir

    def other_run_publishes_first(tmp, out_dir, overwrite=False):
        shutil.copytree(other, out_dir)  # the other run's sequence took the name meanwhile
        return real(tmp, out_dir, overwrite)

    monkeypatch.setattr(writer, "publish_tmp_dir", other_run_publishes_first)
    capsys.readouterr()
    assert _main(_render_argv(tmp_path, "--out", str(seq))) == 2
    assert capsys.readouterr().err.strip().splitlines() == [
        f"crowdsim render: error: {seq} already exists; pass --overwrite to replace it"
    ]
    assert not_ours(seq) is None
    assert sorted(p.name for p in tmp_path.iterdir()) == ["other", "seq", "walk.csv"]
