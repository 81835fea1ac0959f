"""Detector training: data kept apart from the held-out sets, aligned crops, resumable and
seeded training, a refused foreign folder, detection births while tracking."""

from __future__ import annotations

import json

import numpy as np
import pytest

from crowdsim.lab import detector as lab

torch = pytest.importorskip("torch")

TINY = lab.TrainConfig(
    sequences=3, frames_per_sequence=1, iterations=6, batch=2, crop=64, checkpoint_every=3
)


def test_training_sequences_never_share_a_seed_with_the_heldout_ones():
    specs = lab.training_specs(lab.TrainConfig(sequences=30))
    kinds = [k for k, _ in specs]
    assert kinds.count("default") == 9 and kinds.count("ucf9") == 9 and kinds.count("hard") == 12
    held = {s.seed for _, _, s in lab.heldout_specs()}
    assert held.isdisjoint({s.seed for _, s in specs})
    assert {s.appearance.template_px for _, s in specs if _ != "ucf9"} <= set(lab.TEMPLATES)


@pytest.mark.parametrize("seed", range(6))
def test_augmented_crops_keep_every_point_on_its_pixel(seed):
    rng = np.random.default_rng(seed)
    frame = np.full((90, 130, 3), 100, np.uint8)
    pts = np.array([[20.0, 30.0], [100.0, 70.0], [64.0, 12.0]])
    for x, y in pts.astype(int):
        frame[y, x] = 255
    patch, moved, scale = lab._augment(frame, pts, rng, 64)
    assert patch.shape == (64, 64, 3)
    for x, y in moved:  # each kept point lands on (or next to, after a rescale) its bright dot
        yi, xi = int(round(y)), int(round(x))
        win = patch[max(yi - 1, 0) : yi + 2, max(xi - 1, 0) : xi + 2, 0]
        assert win.max() > 100 + 10 * scale, (x, y, scale)


def _weights(path):
    return torch.load(path / "head_points.pt", weights_only=True)["state_dict"]


def test_a_seed_gives_the_same_weights_and_a_resumed_run_equals_an_unbroken_one(
    tmp_path, monkeypatch
):
    lab.train(tmp_path / "a", TINY, progress=False, log=lambda m: None)
    lab.train(tmp_path / "b", TINY, progress=False, log=lambda m: None)
    a, b = _weights(tmp_path / "a"), _weights(tmp_path / "b")
    assert all(torch.equal(a[k], b[k]) for k in a)
    assert (tmp_path / "a" / "loss.png").stat().st_size > 0
    rec = json.loads((tmp_path / "a" / "head_points.json").read_text())
    assert rec["config"]["iterations"] == 6 and rec["data"]["frames"] == 3

    calls = {"n": 0}
    real = lab._loss

    def dying(*args):
        calls["n"] += 1
        if calls["n"] == 5:  # after the checkpoint at step 3
            raise KeyboardInterrupt
        return real(*args)

    monkeypatch.setattr(lab, "_loss", dying)
    with pytest.raises(KeyboardInterrupt):
        lab.train(tmp_path / "c", TINY, progress=False, log=lambda m: None)
    assert (tmp_path / "c" / "checkpoint.pt").is_file()
    assert not (tmp_path / "c" / "head_points.pt").exists()
    monkeypatch.setattr(lab, "_loss", real)
    said = []
    lab.train(tmp_path / "c", TINY, progress=False, log=said.append)
    assert any("resuming" in m and "step 3" in m for m in said)
    c = _weights(tmp_path / "c")
    assert all(torch.equal(a[k], c[k]) for k in a)
    assert not (tmp_path / "c" / "checkpoint.pt").exists()


def test_a_foreign_folder_or_other_settings_are_refused(tmp_path):
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "notes.txt").write_text("keep me")
    with pytest.raises(ValueError, match="did not make"):
        lab.train(mine, TINY, progress=False, log=lambda m: None)
    assert (mine / "notes.txt").read_text() == "keep me"
    run = tmp_path / "run"
    run.mkdir()
    (run / lab.MARKER).write_text(json.dumps({"config": {"seed": 5}}))
    with pytest.raises(ValueError, match="other settings"):
        lab.train(run, TINY, progress=False, log=lambda m: None)


def test_a_rerun_replaces_its_own_outputs_but_not_a_users_edit(tmp_path):
    """The outputs' digests are in the folder's ledger: a rerun with the same settings
    replaces them; an edited ``head_points.json`` is refused before any work unless
    ``overwrite``; a folder from before the ledger vouches for its own."""
    from crowdsim.atomic import LEDGER

    run = tmp_path / "run"
    lab.train(run, TINY, progress=False, log=lambda m: None)
    lab.train(run, TINY, progress=False, log=lambda m: None)  # its own: replaced
    (run / "head_points.json").write_text('{"my": "notes"}')
    with pytest.raises(ValueError, match="head_points.json: the file exists and crowdsim"):
        lab.train(run, TINY, progress=False, log=lambda m: None)
    assert (run / "head_points.json").read_text() == '{"my": "notes"}'
    lab.train(run, TINY, progress=False, log=lambda m: None, overwrite=True)
    assert json.loads((run / "head_points.json").read_text())["config"]["iterations"] == 6
    (run / LEDGER).unlink()  # as a release before the ledger left it
    (run / "loss.png").write_bytes(b"edited")
    lab.train(run, TINY, progress=False, log=lambda m: None)
    assert (run / "loss.png").read_bytes() != b"edited" and (run / LEDGER).is_file()


def test_relabel_gives_matched_heads_the_truths_ids():
    gt_ids = np.array([4, 9, 12])
    gt = np.array([[10.0, 10.0], [30.0, 10.0], [np.nan, np.nan]])
    ids, matched = lab.relabel_to_truth(
        np.array([[31.0, 11.0], [80.0, 80.0], [12, 10]]), gt_ids, gt
    )
    assert ids.tolist() == [9, 14, 4] and matched.tolist() == [4, 9]


def test_the_tracking_table_tracks_with_the_threshold_and_frames_it_is_given(monkeypatch):
    """detector eval --tracking --threshold T --tracking-frames N: every sequence is tracked
    with the detector at T and cut to N frames (T had been dropped: the tracking part always
    ran at the default threshold, whole sequences)."""
    calls = []

    def fake(spec, **kw):
        calls.append((spec.name, kw))
        scores = {"acc@15": 90.0, "acc@5": 80.0}
        return {"sequence": spec.name, "ground truth": scores, "detections": scores}

    monkeypatch.setattr(lab, "track_from_detections", fake)
    tab = lab.tracking_table(tracker="ncc", threshold=0.55, frames=12, progress=False)
    assert [name for name, _ in calls] == [f"seq{i}" for i in range(1, 10)]
    assert all(
        kw["threshold"] == 0.55 and kw["frames"] == 12 and kw["tracker"] == "ncc" for _, kw in calls
    )
    assert tab["frames"] == 12 and tab["gap_acc15"] == 0.0
