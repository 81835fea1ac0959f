"""The classical LoG head detector (tracker.detect.classical): planted discs recovered to
sub-pixel, polarity, threshold monotonicity, parameter validation and the threshold fit."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from crowdsim.detections import Detections
from tracker.detect.classical import HEAD_FRACTION, LogDetector, LogParams, fit_threshold
from tracker.detect.matching import DetectionScore, match_points, score_frame

TEMPLATE = 20  # head diameter 0.42 * 20 = 8.4 px
GROUND = 128


def _plant(
    centres: np.ndarray,
    size: tuple[int, int],
    grey: np.ndarray | int,
    noise: float = 0.0,
    rng: np.random.Generator | None = None,
) -> np.ndarray:
    """A grey-ground BGR frame with anti-aliased head discs at sub-pixel ``centres``."""
    w, h = size
    img = np.full((h, w, 3), GROUND, np.uint8)
    greys = np.broadcast_to(np.asarray(grey), (len(centres),))
    r = HEAD_FRACTION * TEMPLATE / 2
    for (x, y), g in zip(centres, greys, strict=True):
        c = (int(round(x * 16)), int(round(y * 16)))
        cv2.circle(img, c, int(round(r * 16)), (int(g),) * 3, -1, cv2.LINE_AA, 4)
    if noise > 0:
        assert rng is not None
        img = np.clip(img + rng.normal(0.0, noise, img.shape), 0, 255).astype(np.uint8)
    return img


def _grid(rng: np.random.Generator, cols: int = 8, rows: int = 5) -> np.ndarray:
    gx, gy = np.meshgrid(20 + 35 * np.arange(cols), 20 + 40 * np.arange(rows))
    return np.stack([gx.ravel(), gy.ravel()], 1) + rng.uniform(-0.5, 0.5, (cols * rows, 2))


def test_planted_dark_discs_found_to_sub_pixel():
    centres = _grid(np.random.default_rng(1))
    frame = _plant(centres, (300, 200), 40)
    pts, scores = LogDetector(LogParams(template_px=TEMPLATE, threshold=20.0)).detect_points(frame)
    assert pts.shape == (len(centres), 2) and scores.shape == (len(centres),)
    p, g, d = match_points(pts, centres, 1.0)
    assert len(p) == len(centres)  # all found, and no false alarm (same count)
    # Sub-pixel refinement: the integer peak alone is up to 0.7 px off on this grid.
    assert d.max() < 0.15
    # Scores: R / (R + threshold), R ~ the 88 grey levels of contrast.
    assert np.all((scores > 0.75) & (scores < 0.85))


def test_response_reads_as_contrast_at_the_disc_centre():
    # Eq. 1 normalisation: a head-sized disc c grey levels darker gives R ~ c (the AA edge and
    # the discrete disc make it a few percent less).
    frame = _plant(np.array([[50.0, 40.0]]), (100, 80), GROUND - 60)
    det = LogDetector(LogParams(template_px=TEMPLATE, threshold=1.0, polarity="dark"))
    assert det.response(frame)[40, 50] == pytest.approx(60.0, rel=0.1)
    assert LogParams(template_px=TEMPLATE).sigma == pytest.approx(0.42 * 20 / (2 * math.sqrt(2)))


def test_centre_half_way_between_pixels_gives_one_detection():
    frame = _plant(np.array([[30.5, 20.5]]), (60, 40), 40)
    pts, _ = LogDetector(LogParams(template_px=TEMPLATE, threshold=20.0)).detect_points(frame)
    assert pts.shape == (1, 2)
    assert np.abs(pts[0] - [30.5, 20.5]).max() < 0.1


def test_exact_tie_in_one_window_gives_one_peak():
    # A plateau of two equal pixels (rendered images almost never tie exactly, a response
    # map can): the first in raster order is kept, refined half-way towards the other.
    response = np.zeros((20, 30), np.float32)
    response[10, 14:16] = 50.0
    response[10, 13] = response[10, 16] = 30.0
    response[3, 28] = 40.0  # a separate peak, 13 px away along x
    det = LogDetector(LogParams(template_px=TEMPLATE, threshold=20.0))
    pts, values = det.peaks(response, 20.0)
    assert pts.tolist() == [[28.0, 3.0], [14.5, 10.0]] and values.tolist() == [40.0, 50.0]


@pytest.mark.parametrize(
    ("polarity", "found"),
    [("dark", [0, 1]), ("bright", [2, 3]), ("both", [0, 1, 2, 3])],
)
def test_polarity(polarity, found):
    centres = np.array([[20.0, 20.0], [60.0, 20.0], [20.0, 60.0], [60.0, 60.0]])
    frame = _plant(centres, (80, 80), np.array([40, 60, 220, 200]))
    det = LogDetector(LogParams(template_px=TEMPLATE, threshold=20.0, polarity=polarity))
    pts, _ = det.detect_points(frame)
    p, g, _ = match_points(pts, centres, 1.0)
    assert len(pts) == len(found) and sorted(g.tolist()) == found


def test_higher_threshold_gives_a_subset():
    rng = np.random.default_rng(2)
    centres = _grid(rng)
    frame = _plant(centres, (300, 200), rng.integers(60, 125, len(centres)), 10.0, rng)
    previous = None
    counts = []
    for t in (5.0, 10.0, 20.0, 30.0, 45.0, 60.0):
        pts, scores = LogDetector(LogParams(template_px=TEMPLATE, threshold=t)).detect_points(frame)
        assert np.all(scores >= 0.5)
        if previous is not None:
            kept = {tuple(p) for p in pts.tolist()}
            assert kept <= previous
        previous = {tuple(p) for p in pts.tolist()}
        counts.append(len(pts))
    assert counts == sorted(counts, reverse=True) and counts[0] > counts[-1] > 0


def test_uniform_frame_and_edge_cases():
    det = LogDetector(LogParams(template_px=12, threshold=5.0))
    pts, scores = det.detect_points(np.full((30, 40, 3), 100, np.uint8))
    assert pts.shape == (0, 2) and scores.shape == (0,)
    dets = det.detect(np.full((30, 40, 3), 100, np.uint8))
    assert isinstance(dets, Detections) and len(dets) == 0
    with pytest.raises(ValueError, match=r"frame must have shape \(H, W, 3\)"):
        det.detect_points(np.zeros((30, 40, 4), np.uint8))
    with pytest.raises(ValueError, match="params must be a LogParams"):
        LogDetector({"template_px": 12})  # type: ignore[arg-type]


def test_detect_returns_template_boxes():
    frame = _plant(np.array([[30.0, 25.0]]), (60, 50), 40)
    det = LogDetector(LogParams(template_px=TEMPLATE, threshold=20.0))
    dets = det.detect(frame)
    pts, scores = det.detect_points(frame)
    assert len(dets) == 1
    assert np.allclose(dets.xyxy, [[20.0, 15.0, 40.0, 35.0]], atol=0.1)
    assert np.allclose(dets.confidence, scores)


@pytest.mark.parametrize(
    ("kwargs", "field"),
    [
        ({"template_px": 1.5}, "template_px"),
        ({"template_px": 300}, "template_px"),
        ({"template_px": float("nan")}, "template_px"),
        ({"template_px": 12, "threshold": 0.0}, "threshold"),
        ({"template_px": 12, "threshold": -1.0}, "threshold"),
        ({"template_px": 12, "min_distance_px": 0.5}, "min_distance_px"),
        ({"template_px": 12, "polarity": "light"}, "polarity"),
        ({"template_px": 12, "head_fraction": 0.0}, "head_fraction"),
    ],
)
def test_bad_params_name_the_field(kwargs, field):
    with pytest.raises(ValueError, match=f"LogParams.{field} must be"):
        LogParams(**kwargs)


def test_min_distance_window():
    # Two discs 8 px apart along x: one detection with the default window (d = 10 px), two
    # with d = 3 px.
    frame = _plant(np.array([[30.0, 30.0], [38.0, 30.0]]), (70, 60), 30)
    # (Dark polarity: the bright lobes beside the pair would be peaks of |R| too.)
    wide = LogDetector(LogParams(template_px=TEMPLATE, threshold=20.0, polarity="dark"))
    narrow = LogDetector(
        LogParams(template_px=TEMPLATE, threshold=20.0, min_distance_px=3, polarity="dark")
    )
    assert wide.params.window_half_px == 10 and narrow.params.window_half_px == 3
    assert len(wide.detect_points(frame)[0]) == 1
    assert len(narrow.detect_points(frame)[0]) == 2


def _noisy_set(seed: int, frames: int) -> tuple[list[np.ndarray], list[np.ndarray]]:
    rng = np.random.default_rng(seed)
    imgs, gts = [], []
    for _ in range(frames):
        centres = _grid(rng)
        keep = rng.random(len(centres)) < 0.8
        # Half-present heads of weak contrast would be ambiguous: heads are 50-90 grey levels
        # dark; faint blobs (8-15 grey levels, no ground truth) are clutter to be rejected.
        clutter = _grid(rng) + [17.0, 0.0]
        frame = _plant(centres[keep], (300, 200), rng.integers(40, 80, int(keep.sum())))
        frame = _plant_over(frame, clutter[rng.random(len(clutter)) < 0.3], rng)
        frame = np.clip(frame + rng.normal(0.0, 6.0, frame.shape), 0, 255).astype(np.uint8)
        gt = centres.copy()
        gt[~keep] = np.nan
        imgs.append(frame)
        gts.append(gt)
    return imgs, gts


def _plant_over(frame: np.ndarray, centres: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    r = HEAD_FRACTION * TEMPLATE / 2
    for x, y in centres:
        g = int(GROUND - rng.integers(8, 16))
        c = (int(round(x * 16)), int(round(y * 16)))
        cv2.circle(frame, c, int(round(r * 16)), (g,) * 3, -1, cv2.LINE_AA, 4)
    return frame


def test_fit_threshold_separates_heads_from_clutter():
    train_f, train_g = _noisy_set(10, 3)
    test_f, test_g = _noisy_set(11, 3)
    t = fit_threshold(train_f, train_g, TEMPLATE)
    # Every threshold between the clutter's peaks (<= 15.5) and the heads' (>= 45) gives
    # F1 = 1 on the training frames; the fit takes the middle of that plateau (26.4).
    assert 20.0 < t < 35.0
    det = LogDetector(LogParams(template_px=TEMPLATE, threshold=t))
    score = sum(
        (score_frame(det.detect_points(f)[0], g) for f, g in zip(test_f, test_g, strict=True)),
        DetectionScore(),
    )
    assert score.f1 >= 0.95
    # A threshold far off either way does worse on the same frames.
    for bad in (5.0, 80.0):
        off = LogDetector(LogParams(template_px=TEMPLATE, threshold=bad))
        worse = sum(
            (score_frame(off.detect_points(f)[0], g) for f, g in zip(test_f, test_g, strict=True)),
            DetectionScore(),
        )
        assert worse.f1 < score.f1


def test_fit_threshold_bad_input():
    with pytest.raises(ValueError, match="at least one frame"):
        fit_threshold([], [], TEMPLATE)
    frame = np.full((20, 20, 3), 128, np.uint8)
    with pytest.raises(ValueError, match="1 frames but 2 ground truths"):
        fit_threshold([frame], [np.zeros((0, 2)), np.zeros((0, 2))], TEMPLATE)
    with pytest.raises(ValueError, match="LogParams.template_px"):
        fit_threshold([frame], [np.zeros((0, 2))], 1)
    with pytest.raises(ValueError, match="fit_threshold.n_candidates"):
        fit_threshold([frame], [np.zeros((0, 2))], TEMPLATE, n_candidates=1)
