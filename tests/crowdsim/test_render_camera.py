"""Camera: metres -> pixels, tilt homography, jitter, clipping."""

from __future__ import annotations

import numpy as np
import pytest

from crowdsim.camera import Camera


def test_untilted_camera_is_an_affine_top_down_map():
    cam = Camera(px_per_m=20.0, width=200, height=100, center=(1.0, 2.0))
    px = cam.project(np.array([[1.0, 2.0], [2.0, 2.0], [1.0, 3.0]]))
    np.testing.assert_allclose(px, [[100, 50], [120, 50], [100, 70]])
    np.testing.assert_allclose(cam.unproject(px), [[1, 2], [2, 2], [1, 3]], atol=1e-12)


def test_tilt_keeps_the_centre_and_shrinks_the_far_top():
    cam = Camera(
        px_per_m=10.0, width=200, height=200, center=(0.0, 0.0), tilt_deg=30, distance_m=20.0
    )
    np.testing.assert_allclose(cam.project(np.zeros(2)), [100, 100])
    top, mid, bottom = cam.scale_at(np.array([[0.0, -5.0], [0.0, 0.0], [0.0, 5.0]]))
    assert top < mid < bottom
    assert mid == pytest.approx(10.0, rel=1e-3)
    pts = np.random.default_rng(0).uniform(-5, 5, (50, 2))
    np.testing.assert_allclose(cam.unproject(cam.project(pts)), pts, atol=1e-9)


def test_nan_stays_nan_and_visibility_clips():
    cam = Camera(px_per_m=10.0, width=100, height=50)
    px = cam.project(np.array([[np.nan, 0.0], [0.0, 0.0], [100.0, 0.0]]))
    assert np.isnan(px[0]).all()
    np.testing.assert_array_equal(cam.visible(px), [False, True, False])


def test_jitter_is_seeded_smooth_and_has_the_requested_size():
    cam = Camera(px_per_m=10.0, width=64, height=64, jitter_px=2.0, seed=5)
    a = cam.jitter(4000)
    np.testing.assert_array_equal(a, cam.jitter(4000))
    np.testing.assert_array_equal(a[:100], cam.jitter(100))  # prefix-stable
    assert 1.5 < a.std() < 2.5
    assert np.abs(np.diff(a, axis=0)).mean() < a.std()  # correlated frame to frame
    assert not np.array_equal(
        a, Camera(px_per_m=10.0, width=64, height=64, jitter_px=2.0, seed=6).jitter(4000)
    )
    assert not Camera(px_per_m=10.0, width=64, height=64).jitter(10).any()


def test_fit_covers_the_extent():
    cam = Camera.fit((0.0, 0.0, 10.0, 5.0), px_per_m=20.0, margin_m=1.0)
    assert (cam.width, cam.height) == (240, 140)
    corners = cam.project(np.array([[0.0, 0.0], [10.0, 5.0]]))
    assert cam.visible(corners).all()
    cam = Camera.fit((0.0, 0.0, 10.0, 5.0), size=(120, 120), margin_m=0.0)
    assert cam.px_per_m == pytest.approx(12.0)


@pytest.mark.parametrize(
    "kwargs, field",
    [
        ({"px_per_m": 0.0}, "px_per_m"),
        ({"width": 3}, "width"),
        ({"tilt_deg": 75.0}, "tilt_deg"),
        ({"jitter_px": -1.0}, "jitter_px"),
        ({"center": (0.0, float("nan"))}, "center"),
    ],
)
def test_bad_camera_values_name_the_field(kwargs, field):
    base = {"px_per_m": 10.0, "width": 64, "height": 64}
    base.update(kwargs)
    with pytest.raises(ValueError, match=f"camera.{field}"):
        Camera(**base)


def test_jitter_frames_sets_how_fast_the_camera_shakes():
    def lag1(frames):
        a = Camera(
            px_per_m=10.0, width=64, height=64, jitter_px=2.0, seed=5, jitter_frames=frames
        ).jitter(4000)[:, 0]
        assert 1.5 < a.std() < 2.5  # same size of shake
        return np.corrcoef(a[:-1], a[1:])[0, 1]

    assert lag1(12.0) > 0.85  # slow sway (the default)
    assert lag1(1.0) < 0.5  # fast shake
    with pytest.raises(ValueError, match="camera.jitter_frames"):
        Camera(px_per_m=10.0, width=64, height=64, jitter_frames=0.0)
