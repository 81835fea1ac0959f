"""Mean-shift baseline (paper 2's MS): OpenCV mean-shift on colour-histogram back-projection."""

from __future__ import annotations

from dataclasses import fields, replace

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tracker.appearance import extract_patches, padded_origins
from tracker.baselines.meanshift import (
    _SPACE,
    COLOR_SPACES,
    MeanShiftParams,
    MeanShiftTracker,
    bin_index,
    channel_bins,
    histograms,
    shift_windows,
)
from tracker.registry import make_tracker
from tracker.testing import make_scene

SCENE = dict(
    starts=[[20, 20], [90, 20], [100, 75], [25, 75]],
    velocities=[[2, 1], [-2, 1], [-2, 0], [1, -1]],
    n_frames=12,
)


def _scene():
    return make_scene(**SCENE)


@pytest.mark.parametrize("space", COLOR_SPACES)
def test_follows_coloured_blobs(space):
    sc = _scene()
    t = MeanShiftTracker(MeanShiftParams(color_space=space))
    res = t.track(sc.frames, sc.ids, sc.points[0], sc.template_size)
    # the mode of a two-tone blob's back-projection sits within 2 px of its centre
    assert np.abs(res.positions - sc.points).max() <= 2
    assert t.confidence.shape == (4,) and (t.confidence > 0.5).all()


def test_histograms_and_bins():
    img = np.array([[[0, 0, 0], [255, 255, 255], [0, 128, 255]]], np.uint8)
    assert bin_index(img, "bgr", 2).tolist() == [[0, 7, 3]]
    hsv = np.array([[[179, 255, 0], [90, 0, 255]]], np.uint8)  # already converted
    assert bin_index(hsv, "hue", 4).tolist() == [[3, 2]]
    assert bin_index(hsv, "hsv", 2).tolist() == [[3, 2]]
    h = histograms(np.array([[0, 0, 1, 3]]), 4)
    np.testing.assert_allclose(h, [[0.5, 0.25, 0.0, 0.25]])
    np.testing.assert_allclose(np.sqrt(h * h).sum(1), 1.0)  # Bhattacharyya of itself


def _cv2_windows(image, tl, hists, space, bins, s, r, max_iter, epsilon):
    """What the compiled pass replaced: the regions binned and back-projected in numpy, then
    ``cv2.meanShift`` one target at a time, and the histogram under each final window."""
    side = s + 2 * r
    idx = bin_index(extract_patches(image, tl, side).transpose(0, 2, 3, 1), space, bins)
    top = np.maximum(hists.max(1, keepdims=True), 1e-12)
    back = np.rint(255.0 * np.take_along_axis(hists / top, idx.reshape(len(tl), -1), 1))
    back = back.reshape(idx.shape).astype(np.uint8)
    criteria = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, max_iter, epsilon)
    win = np.array([cv2.meanShift(b, (r, r, s, s), criteria)[1][:2] for b in back], np.int64)
    d = np.arange(s)
    rows = (win[:, 1:2] + d)[:, :, None]
    cols = (win[:, 0:1] + d)[:, None, :]
    return win, histograms(idx[np.arange(len(tl))[:, None, None], rows, cols], hists.shape[1])


@settings(max_examples=60, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    space=st.sampled_from(COLOR_SPACES),
    bins=st.integers(2, 6),
    s=st.integers(2, 15),
    r=st.integers(1, 9),
    max_iter=st.integers(1, 12),
    epsilon=st.sampled_from([0.3, 0.5, 1.0, 1.5, 2.0, 3.0]),
)
def test_compiled_search_finds_opencv_meanshift_windows(seed, space, bins, s, r, max_iter, epsilon):
    rng = np.random.default_rng(seed)
    # blocky colours (runs of equal bins) so that windows move, on a frame the regions leave
    small = rng.integers(0, 256, (rng.integers(2, 9), rng.integers(2, 9), 3), dtype=np.uint8)
    image = cv2.resize(small, (int(rng.integers(8, 40)), int(rng.integers(8, 40))), 0, 0, 0)
    n = 12
    n_bins = bins ** len(_SPACE[space][1])
    hists = rng.random((n, n_bins)) * (rng.random((n, n_bins)) < 0.4)
    hists[0] = 0.0  # a histogram that scores no pixel: the window stays
    hists /= np.maximum(hists.sum(1, keepdims=True), 1.0)
    tl = rng.integers(-s - 2 * r - 3, np.array(image.shape[1::-1]) + 3, (n, 2))
    want_win, want_under = _cv2_windows(image, tl, hists, space, bins, s, r, max_iter, epsilon)
    padded, ox, oy = padded_origins(image, tl, s + 2 * r)
    top = np.maximum(hists.max(1, keepdims=True), 1e-12)
    channels = np.array(_SPACE[space][1], np.int64)
    lut = channel_bins(space, bins)
    eps2 = int(np.rint(epsilon * epsilon))
    scale = hists / top
    win, under = shift_windows(padded, ox, oy, scale, channels, lut, bins, s, r, max_iter, eps2)
    np.testing.assert_array_equal(win, want_win)
    np.testing.assert_array_equal(under, want_under)
    assert (win[0] == r).all()


def test_registry_determinism_and_edge_cases():
    sc = _scene()
    a, b = (make_tracker("meanshift").track(sc.frames, sc.ids, sc.points[0], 8) for _ in range(2))
    np.testing.assert_array_equal(a.positions, b.positions)
    res = MeanShiftTracker().track(sc.frames[:3], [], np.zeros((0, 2)), 8)
    assert res.positions.shape == (3, 0, 2)
    one = make_scene([[40, 40]], [[1, 2]], n_frames=6)
    res = MeanShiftTracker().track(one.frames, one.ids, one.points[0], 8)
    assert np.abs(res.positions - one.points).max() <= 2
    flat = [np.full((60, 80, 3), 100, np.uint8)] * 5
    res = MeanShiftTracker().track(flat, [1, 2], np.array([[20.0, 20.0], [60.0, 40.0]]), 8)
    np.testing.assert_array_equal(
        res.positions, np.broadcast_to(res.positions[0], res.positions.shape)
    )


CHANGES = {
    "color_space": "hsv",
    "bins": 4,
    "search_factor": 3.0,
    "max_iter": 1,
    "epsilon": 5.0,
    "update_every": 1,
    "update_threshold": 0.99,
    "lost_ratio": 0.99,
    "max_lost": 1,
    "cmc": True,
    "cmc_method": "ecc",
}


def _snapshot(t: MeanShiftTracker) -> tuple:
    return (
        t.points.tobytes(),
        t.confidence.tobytes(),
        t.hists.tobytes(),
        t.radius,
        t.templates.tobytes(),
        t.age.tobytes(),
    )


def _run(params, switch_to, frames, p0):
    t = MeanShiftTracker(params)
    t.init(frames[0], np.arange(1, len(p0) + 1), p0, 8)
    if switch_to is not None:
        t.set_params(switch_to)
    out = []
    for f in frames[1:]:
        t.step(f)
        out.append(_snapshot(t))
    return out


def test_every_parameter_takes_effect_mid_sequence():
    assert set(CHANGES) == {f.name for f in fields(MeanShiftParams)}
    # 12 frames: the histograms are refreshed once (update_every = 10)
    sc = make_scene(SCENE["starts"], [[2, 2], [-2, 2], [-3, 0], [2, -2]], n_frames=12)
    p0 = sc.points[0]
    base = _run(MeanShiftParams(), None, sc.frames, p0)
    for name, value in CHANGES.items():
        new = replace(MeanShiftParams(), **{name: value})
        switched = _run(MeanShiftParams(), new, sc.frames, p0)
        assert switched == _run(new, None, sc.frames, p0), name  # as if set from the start
        # no track is lost on this scene, its camera is still and cmc_method needs cmc on
        # (test_cmc.py shows both at work under camera shake)
        if name not in ("max_lost", "cmc", "cmc_method"):
            assert switched != base, name  # and it changes what the tracker does


@pytest.mark.parametrize(
    "field,value",
    [
        ("color_space", "lab"),
        ("bins", 1),
        ("bins", 300),
        ("bins", 8.5),
        ("search_factor", 1.0),
        ("max_iter", 0),
        ("epsilon", 0.0),
        ("update_every", 0),
        ("update_threshold", 1.5),
    ],
)
def test_bad_params_name_field_and_value(field, value):
    with pytest.raises(ValueError, match=rf"MeanShiftParams\.{field} .*got {value!r}"):
        MeanShiftParams(**{field: value})


def test_meanshift_refreshes_its_histogram_after_exactly_update_every_frames():
    """update_every=2 rebuilds the template on exactly the 2nd frame and restarts its age."""
    grey = np.full((48, 48, 3), 100, np.uint8)
    white = np.full((48, 48, 3), 200, np.uint8)
    tr = MeanShiftTracker(MeanShiftParams(update_every=2, update_threshold=0.0, max_lost=0))
    tr.init(grey, np.array([1]), np.array([[24.0, 24.0]]), 8)
    tr.step(white)
    assert tr.age.tolist() == [1] and (tr.templates == 100).all()
    tr.step(white)
    assert tr.age.tolist() == [0] and (tr.templates == 200).all()
