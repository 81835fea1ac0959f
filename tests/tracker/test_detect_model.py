"""The head-point network's targets, decoding, weights files and input checks."""

from __future__ import annotations

import numpy as np
import pytest

from tracker.detect.model import STRIDE, decode, standardise, targets

torch = pytest.importorskip("torch")


def test_targets_then_decode_recovers_planted_points():
    pts = np.array([[9.0, 4.4], [40.3, 21.7], [2.0, 30.0]])
    heat, cells, off = targets(pts, 12, 16, template_px=12)
    offsets = np.zeros((2, 12, 16), np.float32)
    offsets[:, cells[:, 0], cells[:, 1]] = off.T
    found, scores = decode(heat, offsets, threshold=0.99)
    assert scores.tolist() == [1.0, 1.0, 1.0]
    assert sorted(map(tuple, np.round(found, 4))) == sorted(map(tuple, np.round(pts, 4)))


def test_targets_drop_points_outside_the_map_and_nan_rows():
    pts = np.array([[-9.0, 4.0], [np.nan, 3.0], [4.0, 4.0], [4.0 * 16 + 3, 4.0]])
    heat, cells, _ = targets(pts, 8, 16, template_px=8)
    assert cells.tolist() == [[1, 1]]
    assert heat.max() == 1.0 and (heat >= 1.0).sum() == 1


def test_decode_keeps_only_local_maxima_above_threshold():
    heat = np.zeros((5, 5))
    heat[2, 2], heat[2, 3], heat[0, 0] = 0.9, 0.8, 0.35
    pts, scores = decode(heat, np.zeros((2, 5, 5)), 0.3)
    assert pts.tolist() == [[2 * STRIDE, 2 * STRIDE], [0.0, 0.0]]
    assert scores.tolist() == [0.9, 0.35]


def test_standardise_ignores_brightness_and_contrast():
    rng = np.random.default_rng(0)
    img = rng.integers(40, 120, (1, 16, 20, 3)).astype(np.uint8)
    brighter = (img.astype(np.float64) * 2 + 10).astype(np.uint8)
    a, b = standardise(img), standardise(brighter)
    assert a.shape == (1, 3, 16, 20)
    # the +1 in the denominator keeps flat frames finite; contrast changes barely matter
    np.testing.assert_allclose(a, b, atol=0.05)


@pytest.fixture
def weights(tmp_path):
    from tracker.detect.inference import save_weights
    from tracker.detect.model import Architecture, build_net

    torch.manual_seed(0)
    net = build_net(Architecture())
    path = tmp_path / "w.pt"
    save_weights(path, net, Architecture(), {"note": "test"})
    return path, net


def test_weights_round_trip_gives_the_same_heat_map(weights):
    from tracker.detect.inference import DetectorParams, HeadDetector

    path, net = weights
    det = HeadDetector(DetectorParams(weights=str(path)))
    assert det.meta == {"note": "test"}
    frame = np.random.default_rng(1).integers(0, 255, (37, 50, 3)).astype(np.uint8)
    heat, off = det.heatmap(frame)
    assert heat.shape == (10, 13) and off.shape == (2, 10, 13)
    net.eval()
    x = torch.from_numpy(np.pad(standardise(frame[None]), ((0, 0), (0, 0), (0, 3), (0, 2))))
    with torch.no_grad():
        ref = torch.sigmoid(net(x)[0, 0]).numpy()
    np.testing.assert_allclose(heat, ref, atol=1e-5)


def test_damaged_foreign_and_missing_weights_are_named(tmp_path):
    from tracker.detect.inference import WeightsError, load_weights

    bad = tmp_path / "bad.pt"
    bad.write_bytes(b"\x00not a weights file" * 10)
    with pytest.raises(WeightsError, match="bad.pt: not a readable weights file"):
        load_weights(bad)
    foreign = tmp_path / "foreign.pt"
    torch.save({"state_dict": {}}, foreign)
    with pytest.raises(WeightsError, match="foreign.pt: not a crowdsim head-detector"):
        load_weights(foreign)
    with pytest.raises(WeightsError, match="nothing.pt: no such weights file"):
        load_weights(tmp_path / "nothing.pt")


def test_mismatched_tensors_are_named(tmp_path, weights):
    from tracker.detect.inference import WeightsError, load_weights

    path, _ = weights
    blob = torch.load(path, weights_only=True)
    blob["state_dict"].pop(next(iter(blob["state_dict"])))
    torch.save(blob, tmp_path / "cut.pt")
    with pytest.raises(WeightsError, match="cut.pt: weights do not fit the network"):
        load_weights(tmp_path / "cut.pt")


@pytest.mark.parametrize("threshold", [0.0, 1.0, 1.5, float("nan")])
def test_threshold_outside_the_open_unit_interval_is_refused(threshold):
    from tracker.detect.inference import DetectorParams

    with pytest.raises(ValueError, match="DetectorParams.threshold"):
        DetectorParams(threshold=threshold)


def test_frames_below_the_stride_and_wrong_types_are_refused(weights):
    from tracker.detect.inference import DetectorParams, HeadDetector

    det = HeadDetector(DetectorParams(weights=str(weights[0])))
    with pytest.raises(ValueError, match="smaller than the detector's smallest input"):
        det.detect_points(np.zeros((5, 40, 3), np.uint8))
    with pytest.raises(ValueError, match=r"\(H, W, 3\) uint8"):
        det.detect_points(np.zeros((40, 40), np.uint8))
