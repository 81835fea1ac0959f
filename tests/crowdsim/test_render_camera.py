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
        ({"ground_margin_px": -1}, "ground_margin_px"),
        ({"ground_margin_px": 2.5}, "ground_margin_px"),
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


def _drone_cam(**kw):
    args = {"px_per_m": 10.0, "width": 160, "height": 90, "seed": 4, "drift_px": 12.0}
    args.update(rotate_deg=5.0, zoom=0.1, drone_frames=40.0)
    args.update(kw)
    return Camera(**args)


def test_the_drone_profile_is_seeded_smooth_bounded_and_off_by_default():
    off = Camera(px_per_m=10.0, width=160, height=90)
    assert not off.drone_on and not off.moves
    np.testing.assert_array_equal(off.drone(3), np.tile(np.eye(2, 3), (3, 1, 1)))
    assert off.canvas() == (off, (0, 0))
    cam = _drone_cam()
    m = cam.drone(400)
    np.testing.assert_array_equal(m, cam.drone(400))
    np.testing.assert_array_equal(m[:50], cam.drone(50))  # prefix-stable
    assert not np.array_equal(m, _drone_cam(seed=5).drone(400))
    zoom = np.sqrt(np.abs(np.linalg.det(m[:, :, :2])))
    angle = np.degrees(np.arctan2(m[:, 1, 0], m[:, 0, 0]))
    centre = np.array([80.0, 45.0])
    drift = np.einsum("tij,j->ti", m[:, :, :2], centre) + m[:, :, 2] - centre
    assert np.abs(zoom - 1).max() <= 0.1 + 1e-12 and np.abs(zoom - 1).max() > 0.05
    assert np.abs(angle).max() <= 5 + 1e-9 and np.abs(angle).max() > 2.5
    assert np.abs(drift).max() <= 12 + 1e-9 and np.abs(drift).max() > 6
    assert np.abs(np.diff(drift, axis=0)).max() < 12 * 2 * np.pi / 20  # no faster than P/2


def test_the_canvas_covers_every_view_and_sees_the_same_ground_offset():
    cam = _drone_cam(tilt_deg=20.0, jitter_px=1.0)
    big, (mx, my) = cam.canvas()
    assert not big.drone_on and (big.width, big.height) == (160 + 2 * mx, 90 + 2 * my)
    pts = np.random.default_rng(0).uniform(-4, 4, (20, 2))
    np.testing.assert_allclose(big.project(pts), cam.project(pts) + [mx, my], atol=1e-9)
    np.testing.assert_array_equal(big.jitter(30), cam.jitter(30))
    corners = np.array([[0.0, 0.0], [159.0, 0.0], [0.0, 89.0], [159.0, 89.0]])
    for view in cam.drone(300):
        src = (corners - view[:, 2]) @ np.linalg.inv(view[:, :2]).T + [mx, my]
        assert (src >= 1).all() and (src[:, 0] <= big.width - 2).all()
        assert (src[:, 1] <= big.height - 2).all()


@pytest.mark.parametrize("field", ["drift_px", "rotate_deg", "zoom", "drone_frames"])
def test_bad_drone_values_name_the_field(field):
    with pytest.raises(ValueError, match=f"camera.{field}"):
        _drone_cam(**{field: -1.0})


def test_a_drone_scene_draws_each_head_where_the_ground_truth_puts_it():
    """Dark heads on a light ground, no noise: the pixel under every ground-truth head is
    dark on every frame of a drifting, turning, zooming view (measured: mean grey 31 against
    a median of 114), and the camera-motion estimate follows the planted view change."""
    from synth_data.scene import Scene
    from synth_data.spec import spec_from_dict
    from tracker.cmc import MotionCompensator, warp_points

    spec = spec_from_dict(
        {
            "name": "d",
            "seed": 3,
            "frames": 24,
            "scenario": {"name": "marathon", "n_agents": 60},
            "camera": {"drift_px": 25.0, "rotate_deg": 4.0, "zoom": 0.08,
                       "drone_frames": 30.0, "max_width": 320, "max_height": 240},
            "appearance": {"template_px": 12, "noise_sigma": 0.0, "dark_hair_fraction": 1.0},
        },
        source="d.toml",
    )  # fmt: skip
    sc = Scene.from_spec(spec)
    cam = sc.camera
    _, gt = sc.gt_points()
    motion = cam.frame_motion(sc.length)  # the drone's view change (this camera has no shake)
    corners = np.array(
        [[0.0, 0.0], [cam.width - 1, 0], [0, cam.height - 1], [cam.width - 1, cam.height - 1]]
    )
    cmc = MotionCompensator()
    for t in range(sc.length):
        frame = sc.frame(t)
        grey = frame.mean(axis=2)
        p = np.rint(gt[t][np.isfinite(gt[t]).all(1)]).astype(int)
        p = p[(p > 1).all(1) & (p[:, 0] < cam.width - 2) & (p[:, 1] < cam.height - 2)]
        assert len(p) > 10 and grey[p[:, 1], p[:, 0]].mean() < 0.5 * np.median(grey), t
        a = cmc.estimate(frame, exclude=gt[t - 1] if t else None, exclude_px=24)
        if t:
            planted = motion[t - 1]
            assert np.abs(warp_points(a, corners) - warp_points(planted, corners)).max() < 1.5
    assert cmc.failures == 0


def test_a_drone_profile_too_wide_for_any_canvas_is_refused_naming_its_fields():
    with pytest.raises(ValueError, match=r"camera.drift_px / rotate_deg / zoom .*over 16384"):
        Camera(px_per_m=10.0, width=8000, height=8000, drift_px=400, rotate_deg=20, zoom=0.3)


def test_frame_motion_carries_every_ground_point_from_one_frame_to_the_next():
    """``Camera.frame_motion``: a ground point seen at ``q`` in frame ``t - 1`` (projected,
    shaken, then the drone view) is seen at ``frame_motion[t - 1] q`` in frame ``t``."""
    from tracker.cmc import warp_points

    cam = _drone_cam(jitter_px=1.5)
    n = 40
    ground = np.random.default_rng(2).uniform(-3, 3, (25, 2))
    jitter, views, motion = cam.jitter(n), cam.drone(n), cam.frame_motion(n)
    seen = [warp_points(views[t], cam.project(ground) + jitter[t]) for t in range(n)]
    assert motion.shape == (n - 1, 2, 3)
    for t in range(1, n):
        np.testing.assert_allclose(warp_points(motion[t - 1], seen[t - 1]), seen[t], atol=1e-9)
    still = Camera(px_per_m=10.0, width=64, height=48)
    np.testing.assert_array_equal(still.frame_motion(3), np.tile(np.eye(2, 3), (2, 1, 1)))


def test_drone_view_is_a_rotation_and_zoom_about_the_frame_centre():
    """Drone maps are z R(theta) about the frame centre (proper rotation, centre fixed)."""
    cam = Camera(px_per_m=10.0, width=160, height=90, seed=4, rotate_deg=20.0, zoom=0.2)
    m = cam.drone(200)
    lin = m[:, :, :2]
    assert np.abs(lin[:, 1, 0]).max() > 0.1  # it does rotate
    np.testing.assert_allclose(lin[:, 0, 1], -lin[:, 1, 0], atol=1e-12)
    np.testing.assert_allclose(lin[:, 0, 0], lin[:, 1, 1], atol=1e-12)
    centre = np.array([80.0, 45.0])
    np.testing.assert_allclose(lin @ centre + m[:, :, 2], np.tile(centre, (200, 1)), atol=1e-9)


def test_visible_includes_the_last_pixel_row_and_column():
    """visible() includes the last pixel column and row; beyond (or inside margin) is out."""
    cam = Camera(px_per_m=10.0, width=100, height=50)
    px = np.array([[99.0, 49.0], [0.0, 0.0], [99.5, 10.0], [10.0, 49.5], [-0.5, 10.0]])
    np.testing.assert_array_equal(cam.visible(px), [True, True, False, False, False])
    np.testing.assert_array_equal(
        cam.visible(np.array([[97.0, 47.0], [97.5, 20.0], [2.0, 2.0], [1.5, 2.0]]), margin=2.0),
        [True, False, True, False],
    )


def test_a_drone_views_edge_hides_a_head_as_the_frames_edge_does():
    """A head centred on the left edge of the view, under a drone profile that barely moves
    the view, is about half visible, as on a still camera (it had counted as seen in full:
    its visibility was measured up to the larger canvas's edge)."""
    from crowdsim.appearance_model import AppearanceParams
    from crowdsim.render import SceneRenderer

    params = AppearanceParams(template_px=12, noise_sigma=0.0, shadow=0.0)
    seen = {}
    for name, drift in (("still", 0.0), ("drone", 1e-3)):
        cam = Camera(px_per_m=24.0, width=96, height=64, drift_px=drift)
        renderer = SceneRenderer(cam, params, seed=0, fps=25.0)
        vis = np.empty(2)
        pixels = np.array([[0.0, 32.0], [48.0, 32.0]])  # on the edge, and inside
        renderer.render(0, pixels, np.zeros(2), np.zeros(2, np.int64), visibility=vis)
        seen[name] = vis
    assert seen["still"][1] == seen["drone"][1] == 1.0
    assert 0.3 < seen["still"][0] < 0.7
    assert abs(seen["drone"][0] - seen["still"][0]) < 0.1, seen
