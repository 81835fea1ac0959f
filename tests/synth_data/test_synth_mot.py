"""MOT files and the sequence reader (crowdsim sequences and real MOT17/MOT20 layouts)."""

from __future__ import annotations

import re

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from synth_data.mot import read_mot_file, read_sequence, write_mot


def test_write_read_round_trip(tmp_path):
    rows = np.array(
        [[1, 1, 10.5, 20.25, 12, 12, 1, 1, 1.0], [2, 7, -3.125, 4.0, 12, 12, 1, 1, 0.5]]
    )
    path = write_mot(tmp_path / "gt.txt", rows)
    np.testing.assert_allclose(read_mot_file(path), rows)


def test_short_result_rows_are_padded_and_whitespace_is_accepted(tmp_path):
    p = tmp_path / "res.txt"
    p.write_text("1 3 1.0 2.0 3.0 4.0\n\n# comment\n2 3 1.5 2.5 3.0 4.0\n")
    arr = read_mot_file(p)
    assert arr.shape == (2, 9)
    np.testing.assert_array_equal(arr[:, 6:], 1.0)
    empty = tmp_path / "empty.txt"
    empty.write_text("")
    assert read_mot_file(empty).shape == (0, 9)


@pytest.mark.parametrize(
    "content, message",
    [
        ("1,1,2,3,4\n", r"bad\.txt:1: expected at least 6 columns"),
        ("1,1,2,3,4,5,1,1,1\n2,1,2,x,4,5,1,1,1\n", r"bad\.txt:2: non-numeric value 'x'"),
        ("0,1,2,3,4,5,1,1,1\n", r"bad\.txt:1: frame must be a positive integer.*'0'"),
        ("1.5,1,2,3,4,5,1,1,1\n", r"bad\.txt:1: frame must be a positive integer"),
        ("1,1,2,3,-4,5,1,1,1\n", r"bad\.txt:1: box width/height must be >= 0"),
        ("1,1,2,3,4,5,1,1,1\n1,2,2,3,4,5,1,1\n", r"bad\.txt:2: expected 9 columns"),
        ("1,1,nan,3,4,5,1,1,1\n", r"bad\.txt:1: non-finite value"),
    ],
)
def test_malformed_mot_lines_name_file_and_line(tmp_path, content, message):
    p = tmp_path / "bad.txt"
    p.write_text(content)
    with pytest.raises(ValueError, match=message):
        read_mot_file(p)


def test_missing_file_is_a_clear_error(tmp_path):
    with pytest.raises(ValueError, match="no such MOT file"):
        read_mot_file(tmp_path / "nope.txt")


def _mot17_like(root, with_images=True):
    """A tiny folder in the real MOT17 layout: body boxes, several classes, no templateSize."""
    seq = root / "MOT17-XX-FRCNN"
    (seq / "gt").mkdir(parents=True)
    (seq / "seqinfo.ini").write_text(
        "[Sequence]\nname=MOT17-XX\nimDir=img1\nframeRate=30\nseqLength=3\nimWidth=64\n"
        "imHeight=48\nimExt=.jpg\n"
    )
    (seq / "gt" / "gt.txt").write_text(
        "1,1,10,5,20,50,1,1,0.9\n2,1,12,5,20,50,1,1,0.8\n3,1,14,5,20,50,1,1,1\n"
        "1,2,30,8,24,60,1,1,1\n3,2,31,8,24,60,1,1,1\n"
        "1,3,0,0,40,40,0,3,1\n"  # a car, ignored (conf 0, class 3)
        "2,4,5,5,18,40,1,7,1\n"
    )  # a static person (class 7), not a pedestrian target
    if with_images:
        (seq / "img1").mkdir()
        for i in range(1, 4):
            cv2.imwrite(str(seq / "img1" / f"{i:06d}.jpg"), np.full((48, 64, 3), 40 * i, np.uint8))
    return seq


def test_reads_a_real_mot17_layout(tmp_path):
    seq = read_sequence(_mot17_like(tmp_path))
    assert (seq.name, seq.frame_rate, seq.width, seq.height, seq.length) == (
        "MOT17-XX",
        30.0,
        64,
        48,
        3,
    )
    assert seq.box_type == "body"
    assert seq.gt.shape == (7, 9)
    assert seq.template_size == 20  # median width of the pedestrian boxes
    ids, pts = seq.gt_points()
    np.testing.assert_array_equal(ids, [1, 2])
    assert pts.shape == (3, 2, 2)
    np.testing.assert_allclose(pts[0, 0], [20.0, 5 + 0.08 * 50])
    assert np.isnan(pts[1, 1]).all()
    frames = list(seq.frames())
    assert len(frames) == 3 and frames[0].shape == (48, 64, 3) and frames[0].dtype == np.uint8
    assert abs(int(seq.frame(2).mean()) - 80) <= 2
    with pytest.raises(ValueError, match=r"frame must be in \[1, 3\]"):
        seq.frame(0)


def test_a_person_annotated_past_the_image_edge_is_born_when_the_head_enters(tmp_path):
    """Real MOT files annotate people partly outside the image (body boxes past the left
    edge): such a head point is no target yet, so tracking a MOT17 folder from its ground
    truth ran into 'target id 5 starts outside the 64x48 image' (track, compare)."""
    from tracker import make_tracker, run_tracker

    seq_dir = _mot17_like(tmp_path)
    with open(seq_dir / "gt" / "gt.txt", "a") as fh:  # box centre x -6, -2, then 2 (inside)
        fh.write("1,5,-16,10,20,30,1,1,0.4\n2,5,-12,10,20,30,1,1,0.5\n3,5,-8,10,20,30,1,1,0.6\n")
    seq = read_sequence(seq_dir)
    (ids0, _), later = seq.births()
    assert 5 not in ids0.tolist()
    assert {t: v[0].tolist() for t, v in later.items()} == {2: [5]}
    np.testing.assert_allclose(later[2][1], [[2.0, 10 + 0.08 * 30]])
    result = run_tracker(make_tracker("ncc"), seq)  # raised before: target 5 starts outside
    assert 5 in result.result.ids.tolist()


def test_reads_frames_from_video_mp4(tmp_path):
    root = _mot17_like(tmp_path, with_images=False)
    writer = cv2.VideoWriter(
        str(root / "video.mp4"), cv2.VideoWriter_fourcc(*"mp4v"), 30.0, (64, 48)
    )
    if not writer.isOpened():
        pytest.skip("this OpenCV build cannot write mp4v")
    for i in range(1, 4):
        writer.write(np.full((48, 64, 3), 60 * i, np.uint8))
    writer.release()
    seq = read_sequence(root)
    frames = list(seq.frames())
    assert len(frames) == 3 and frames[2].shape == (48, 64, 3)
    assert [round(f.mean() / 60) for f in frames] == [1, 2, 3]
    assert round(seq.frame(3).mean() / 60) == 3


def test_no_gt_gives_an_empty_array_and_the_default_template(tmp_path):
    seq_dir = tmp_path / "s"
    seq_dir.mkdir()
    (seq_dir / "seqinfo.ini").write_text(
        "[Sequence]\nname=s\nframeRate=25\nseqLength=2\nimWidth=32\nimHeight=32\n"
    )
    seq = read_sequence(seq_dir)
    assert seq.gt.shape == (0, 9) and seq.template_size == 12
    ids, pts = seq.gt_points()
    assert ids.shape == (0,) and pts.shape == (2, 0, 2)


@pytest.mark.parametrize("rate, text", [(25.0, "25"), (30000 / 1001, repr(30000 / 1001))])
def test_seqinfo_frame_rate_reads_back_exactly(tmp_path, rate, text):
    from synth_data.mot import write_seqinfo

    seq_dir = tmp_path / "s"
    seq_dir.mkdir()
    write_seqinfo(seq_dir, name="s", frame_rate=rate, length=2, width=32, height=32)
    assert f"\nframeRate={text}\n" in (seq_dir / "seqinfo.ini").read_text()
    assert read_sequence(seq_dir).frame_rate == rate  # 6 digits had read 29.97


@pytest.mark.parametrize(
    "ini, message",
    [
        (None, "missing seqinfo.ini"),
        ("[Other]\nx=1\n", r"missing \[Sequence\] section"),
        ("[Sequence]\nframeRate=25\nimWidth=3\nimHeight=3\n", "missing key 'seqLength'"),
        (
            "[Sequence]\nframeRate=fast\nseqLength=2\nimWidth=3\nimHeight=3\n",
            "key 'frameRate' has a bad value 'fast'",
        ),
    ],
)
def test_bad_sequence_folders_give_clear_errors(tmp_path, ini, message):
    seq_dir = tmp_path / "s"
    seq_dir.mkdir()
    if ini is not None:
        (seq_dir / "seqinfo.ini").write_text(ini)
    with pytest.raises(ValueError, match=message):
        read_sequence(seq_dir)


_row = st.tuples(
    st.integers(1, 10_000),
    st.integers(1, 10_000),
    st.floats(-1e4, 1e4, allow_nan=False),
    st.floats(-1e4, 1e4, allow_nan=False),
    st.floats(0, 500, allow_nan=False),
    st.floats(0, 500, allow_nan=False),
    st.sampled_from([0.0, 1.0]),
    st.integers(1, 12),
    st.floats(0, 1),
)


@settings(max_examples=40, deadline=None)
@given(st.lists(_row, max_size=30))
def test_mot_round_trip_property(tmp_path_factory, rows):
    path = tmp_path_factory.mktemp("mot") / "gt.txt"
    arr = np.array(rows, dtype=float).reshape(-1, 9)
    back = read_mot_file(write_mot(path, arr))
    assert back.shape == arr.shape
    np.testing.assert_array_equal(back[:, [0, 1, 7]], arr[:, [0, 1, 7]])
    np.testing.assert_allclose(back[:, 2:6], arr[:, 2:6], atol=6e-4)
    np.testing.assert_allclose(back[:, 8], arr[:, 8], atol=6e-5)


@pytest.mark.parametrize(
    "text",
    [
        "1,1,10,20,8,8,1,1,1\n2,1,11.5,20,8,8,1,1,0.5\n",  # MOT as written
        "\ufeff1 3 1.5 2 4 4\n\n2 3 2.5 2 4 4\n",  # a BOM, spaces, a blank line, 6 columns
        "1,-1,5,5,3,3,-1,-1,-1,7\n",  # MOT17's -1 and an extra column
        "# a comment\n1,1,10,20,8,8\n",  # comments: the line-by-line reader
    ],
)
def test_the_compiled_reader_reads_what_the_line_reader_reads(tmp_path, monkeypatch, text):
    import synth_data.mot as mot

    p = tmp_path / "r.txt"
    p.write_text(text, encoding="utf-8")
    fast = read_mot_file(p)
    monkeypatch.setattr(mot, "_read_mot_fast", lambda path, min_columns: None)
    np.testing.assert_array_equal(fast, read_mot_file(p))


# ---------------------------------------------------------------------------- ownership
def _listed_sequence(seq):
    """A minimal sequence folder whose ``checksums.json`` lists every file in it."""
    import json

    from synth_data.mot import sha256_file

    (seq / "gt").mkdir(parents=True)
    (seq / "img1").mkdir()
    (seq / "gt" / "gt.txt").write_text("1,1,2,2,8,8,1,1,1\n")
    (seq / "img1" / "000001.jpg").write_bytes(b"\xff\xd8 a frame")
    (seq / "seqinfo.ini").write_text("[Sequence]\nname=s\n")
    listing = {p.relative_to(seq).as_posix(): sha256_file(p) for p in seq.rglob("*") if p.is_file()}
    (seq / "checksums.json").write_text(json.dumps(listing))
    return seq


def test_checksums_entries_must_stay_inside_the_sequence(tmp_path):
    """A listing that names a file outside its folder (``..``, an absolute path, a link out)
    is refused even when that file's digest matches: --overwrite would otherwise count a
    user's file as the sequence's own, and verification would vouch for a foreign file."""
    import json

    from synth_data.mot import check_checksums, not_ours, sha256_file, verify_sequence

    seq = _listed_sequence(tmp_path / "seq")
    mine = tmp_path / "thesis.tex"
    mine.write_text("\\chapter{One}")
    (seq / "link.tex").symlink_to(mine)
    good = json.loads((seq / "checksums.json").read_text())
    assert check_checksums(seq) == good and not_ours(seq) is not None  # link.tex: not listed
    for entry in ("../thesis.tex", str(mine), "link.tex"):
        (seq / "checksums.json").write_text(json.dumps({**good, entry: sha256_file(mine)}))
        with pytest.raises(ValueError, match=re.escape(f"entry {entry!r} points outside")):
            check_checksums(seq)
        assert verify_sequence(seq) is None
        assert "points outside the sequence folder" in not_ours(seq)
    assert mine.read_text() == "\\chapter{One}"


def test_not_ours_names_the_first_file_crowdsim_did_not_write(tmp_path):
    from synth_data.mot import not_ours

    suite = tmp_path / "suite"
    seq = _listed_sequence(suite / "seq")
    assert not_ours(seq) is None
    (suite / "manifest.json").write_text('{"format": 1, "sequences": {}}')
    (suite / ".manifest.json.lock").write_text("")
    assert not_ours(suite) is None
    for plant, named in (
        ("seq/img1/000001_fixed.jpg", "seq/img1/000001_fixed.jpg"),
        ("seq/.DS_Store", "seq/.DS_Store"),
        (".notes", ".notes"),  # hidden, beside the sequences of a suite
        ("seq/gt/mine/labels.txt", "seq/gt/mine/labels.txt"),  # a user's folder: its file
    ):
        (suite / plant).parent.mkdir(parents=True, exist_ok=True)
        (suite / plant).write_text("mine")
        assert not_ours(suite) == f"{suite / named} was not written by crowdsim", plant
        (suite / plant).unlink()
    (seq / "gt" / "mine").rmdir()
    (seq / "empty").mkdir()  # an empty folder of the user's is named itself
    assert not_ours(suite) == f"{seq / 'empty'} was not written by crowdsim"
    (seq / "empty").rmdir()
    (seq / "gt" / "gt.txt").write_text("1,1,3,3,8,8,1,1,1\n")  # a hand correction
    assert "gt.txt: damaged" in not_ours(suite)
    other = tmp_path / "webapp"
    _listed_sequence(other / "seq")
    (other / "manifest.json").write_text('{"name": "my-app", "version": "1.0"}')
    assert (
        not_ours(other)
        == f"{other / 'manifest.json'} is not a crowdsim manifest (no sequences table)"
    )
    assert not_ours(tmp_path / "nothing") == f"{tmp_path / 'nothing'} is not a folder"


def test_mot_ids_rank_negative_ids():
    from synth_data.mot import mot_ids

    assert mot_ids(np.array([5, -1, 3])).tolist() == [3, 1, 2]
    assert mot_ids(np.array([5, 0, 3])).tolist() == [6, 1, 4]


def test_gt_visibility_is_the_boxs_fraction_inside_the_frame():
    """Without a drawn visibility, the column is the share of the head box in the frame: a
    10 px box centred 3 px from the right edge has 8 of its 10 columns inside."""
    from synth_data.mot import gt_rows

    class Camera:
        width, height = 100, 100

        def visible(self, pix):
            x, y = pix[..., 0], pix[..., 1]
            return np.isfinite(pix).all(-1) & (x >= 0) & (x < 100) & (y >= 0) & (y < 100)

    rows = gt_rows(np.array([[[97.0, 50.0]]]), Camera(), 10, np.array([1]))
    assert rows.tolist() == [[1, 1, 92.0, 45.0, 10, 10, 1, 1, 0.8]]


@pytest.mark.parametrize("drawn", [False, True])
def test_gt_rows_by_blocks_of_frames_are_the_rows_of_one_block(monkeypatch, drawn):
    """gt_rows turns a block of frames into rows at a time (memory): blocks of 1 and 2
    frames (3 people a frame) give the rows of one block, sorted by frame then MOT id
    (the ids descend across the columns here, so a block sorted on its own columns only,
    or written at the wrong offset, differs)."""
    import synth_data.mot as mot

    class Camera:
        width, height = 100, 100

        def visible(self, pix):
            x, y = pix[..., 0], pix[..., 1]
            return np.isfinite(pix).all(-1) & (x >= 0) & (x < 100) & (y >= 0) & (y < 100)

    rng = np.random.default_rng(7)
    pix = rng.uniform(-20, 120, (7, 3, 2))
    pix[2, 1] = np.nan
    ids = np.array([9, 4, 2])
    vis = rng.uniform(0, 1, (7, 3)) if drawn else None
    whole = mot.gt_rows(pix, Camera(), 10, ids, vis)
    assert len(whole) and (np.diff(whole[:, 0]) >= 0).all()
    for block in (3, 6):  # 1 and 2 frames of 3 people
        monkeypatch.setattr(mot, "GT_ROWS_BLOCK", block)
        np.testing.assert_array_equal(mot.gt_rows(pix, Camera(), 10, ids, vis), whole)


@pytest.mark.parametrize(("col", "what"), [(0, "frame"), (1, "id"), (7, "class")])
def test_write_mot_refuses_fractional_integer_columns(tmp_path, col, what):
    """``int()`` had written id 2.5 as 2, merging two people, where the reader refuses it."""
    row = np.array([[1, 2, 0, 0, 5, 5, 1, 1, 1.0]])
    row[0, col] += 0.5
    with pytest.raises(ValueError, match=f"MOT row 1: {what} .* is not a whole number"):
        write_mot(tmp_path / "gt.txt", row)
    assert not (tmp_path / "gt.txt").exists()


@settings(max_examples=60, deadline=None)
@given(
    st.lists(
        st.lists(
            st.floats(-1e15, 1e15, allow_nan=False) | st.sampled_from([-0.0, 5e-324, 0.0005]),
            min_size=12,
            max_size=12,
        ),
        max_size=20,
    ),
    st.integers(9, 12),
)
def test_write_mot_text_is_the_per_row_formatting(tmp_path_factory, values, width):
    """The chunked %-format writes the text the per-row f-strings it replaced wrote."""
    rows = np.array(values, dtype=float).reshape(-1, 12)[:, :width]
    rows[:, [0, 1, 7]] = np.round(rows[:, [0, 1, 7]])
    expected = "".join(
        f"{int(r[0])},{int(r[1])},{r[2]:.3f},{r[3]:.3f},{r[4]:.3f},{r[5]:.3f},"
        f"{r[6]:g},{int(r[7])},{r[8]:.4f}" + "".join(f",{v:g}" for v in r[9:]) + "\n"
        for r in rows
    )
    path = write_mot(tmp_path_factory.mktemp("mot") / "gt.txt", rows)
    assert path.read_text() == expected
