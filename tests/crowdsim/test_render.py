"""Renderer: plant people at known points and find them again in the frames."""

from __future__ import annotations

import math

import numpy as np
import pytest

from crowdsim.appearance_model import (
    PROMINENT_COLOURS,
    AppearanceParams,
    appearance_colours,
    build_sprite_bank,
)
from crowdsim.camera import Camera
from crowdsim.render import SceneRenderer, _headings, assign_appearance, prepare_agents
from crowdsim.trajectories import Trajectories
from synth_data.mot import gt_rows, mot_ids, read_sequence
from synth_data.writer import write_sequence


def walkers(n_frames: int = 12, dt: float = 0.04) -> Trajectories:
    """Six agents 3 m apart walking in six directions at 1.3 m/s; one enters late."""
    rng = np.random.default_rng(1)
    start = np.array([[x, y] for y in (2.0, 5.0) for x in (2.0, 5.0, 8.0)])
    start += rng.uniform(-0.2, 0.2, start.shape)  # sub-pixel positions
    ang = np.linspace(0, 2 * math.pi, 6, endpoint=False)
    vel = 1.3 * np.column_stack([np.cos(ang), np.sin(ang)])
    t = np.arange(n_frames)[:, None, None] * dt
    pos = start[None] + vel[None] * t
    pos[:3, 5] = np.nan  # agent 5 enters at row 3
    return Trajectories(
        positions=pos,
        ids=np.arange(10, 16),
        dt=dt,
        attributes={"prominent": np.array([0, 0, 1, 0, 0, 0], bool)},
    )


PARAMS = AppearanceParams(
    template_px=12,
    shadow=0.0,
    noise_sigma=2.0,
    ground_texture=4.0,
    ground_bgr=(60, 170, 60),  # far from every hair colour
    prominent_fraction=0.0,
)
CAMERA = Camera(px_per_m=24.0, width=256, height=176, center=(5.0, 3.5))


def test_plant_and_recover_heads_through_disk(tmp_path):
    traj = walkers()
    write_sequence(tmp_path / "seq", traj, camera=CAMERA, appearance=PARAMS, seed=3)
    seq = read_sequence(tmp_path / "seq")
    assert (seq.width, seq.height, seq.length, seq.template_size) == (256, 176, 12, 12)
    assert seq.box_type == "head"
    ids, points = seq.gt_points()
    np.testing.assert_array_equal(ids, np.arange(11, 17))
    assert np.isnan(points[:3, 5]).all() and np.isfinite(points[3:, 5]).all()
    np.testing.assert_allclose(points, CAMERA.project(traj.positions), atol=2e-3)
    empty = SceneRenderer(CAMERA, PARAMS, seed=3, fps=traj.fps)
    half = 7
    yy, xx = np.mgrid[-half : half + 1, -half : half + 1]
    errors = []
    for t, frame in enumerate(seq.frames()):
        assert frame.shape == (176, 256, 3) and frame.dtype == np.uint8
        ground = empty.render(t, np.zeros((0, 2)), np.zeros(0), np.zeros(0, int))
        diff = np.abs(frame.astype(float) - ground).sum(axis=2)
        for n in range(len(ids)):
            if np.isnan(points[t, n, 0]):
                continue
            u, v = points[t, n]
            cu, cv = int(round(u)), int(round(v))
            assert diff[cv, cu] > 60, "no person drawn at the gt head point"
            win = diff[cv - half : cv + half + 1, cu - half : cu + half + 1]
            w = np.where(win > 30, win, 0.0)
            centroid = np.array([(w * (xx + cu)).sum(), (w * (yy + cv)).sum()]) / w.sum()
            errors.append(np.hypot(*(centroid - (u, v))))
        # Nothing is drawn far away from every person.
        far = np.ones_like(diff, bool)
        for u, v in points[t][np.isfinite(points[t, :, 0])]:
            far[max(0, int(v) - 10) : int(v) + 11, max(0, int(u) - 10) : int(u) + 11] = False
        assert np.percentile(diff[far], 99) < 30
    # The person's centroid sits on the head; shoulders and face bias it a little.
    assert max(errors) < 1.5 and np.mean(errors) < 0.75


def test_same_seed_same_frames_other_seed_other_frames():
    traj = walkers(4)
    frames = []
    for seed in (0, 0, 1):
        r = SceneRenderer(CAMERA, PARAMS, seed=seed, fps=25.0)
        tracks = prepare_agents(traj, CAMERA, PARAMS, seed)
        frames.append(np.stack([r.render_tracks(tracks, t) for t in range(4)]))
    np.testing.assert_array_equal(frames[0], frames[1])
    assert not np.array_equal(frames[0], frames[2])
    assert not np.array_equal(frames[0][0], frames[0][1])  # noise changes frame to frame


def test_headings_follow_motion_and_hold_when_stopped():
    pos = np.zeros((20, 2, 2))
    pos[:, 0, 0] = np.arange(20) * 0.05  # +x at 1.25 m/s
    pos[:10, 1, 1] = np.arange(10) * 0.05  # +y, then stops
    pos[10:, 1, 1] = pos[9, 1, 1]
    traj = Trajectories(positions=pos, ids=np.arange(2), dt=0.04)
    tracks = prepare_agents(traj, CAMERA, AppearanceParams(sway_deg=0.0), seed=0)
    np.testing.assert_allclose(tracks.heading[:, 0], 0.0, atol=1e-9)
    np.testing.assert_allclose(tracks.heading[:, 1], math.pi / 2, atol=1e-9)
    swayed = prepare_agents(traj, CAMERA, AppearanceParams(sway_deg=8.0), seed=0)
    dev = np.degrees(np.abs(swayed.heading[:, 0]))
    assert 1.0 < dev.max() <= 8.0 + 1e-9


def test_a_person_crossing_a_periodic_seam_keeps_heading_and_gait(tmp_path):
    """Walking +x across x = period = 10 m: the heading stays 0 and the gait phase grows by
    the 0.05 m a row walked. Before, the heading turned round near the seam and the gait
    jumped by a period's distance; a CSV gets the period from ``from_csv(period=)``."""
    pos = np.zeros((30, 1, 2))
    pos[:, 0, 0] = (9.5 + np.arange(30) * 0.05) % 10.0
    pos[:, 0, 1] = 3.0
    still = Trajectories(positions=pos.copy(), ids=np.arange(1), dt=0.04)
    periodic = Trajectories(positions=pos.copy(), ids=np.arange(1), dt=0.04, meta={"period": 10})
    plain = AppearanceParams(sway_deg=0.0)
    assert np.ptp(prepare_agents(still, CAMERA, plain, seed=0).heading) > 3  # the old fault
    np.testing.assert_allclose(prepare_agents(periodic, CAMERA, plain, 0).heading, 0, atol=1e-9)
    # with sway the heading is 8 deg * sin(gait): a gait grown by 0.05 m a row turns it by
    # at most 8 deg * 2 pi 0.05 / 1.4 m a row (1.8 deg; it had turned by 181 at the seam)
    swayed = prepare_agents(periodic, CAMERA, AppearanceParams(sway_deg=8.0), seed=0).heading
    assert np.abs(np.diff(swayed[:, 0])).max() <= math.radians(8) * 2 * math.pi * 0.05 / 1.4
    np.testing.assert_allclose(periodic.unwrapped()[:, 0, 0], 9.5 + np.arange(30) * 0.05)
    np.testing.assert_array_equal(periodic.unwrapped()[..., 1], pos[..., 1])
    np.testing.assert_allclose(np.linalg.norm(periodic.velocities()[1:], axis=-1), 1.25)
    still.to_csv(tmp_path / "t.csv")
    back = Trajectories.from_csv(tmp_path / "t.csv", fps=25, period=10.0)
    assert back.period == 10.0
    np.testing.assert_allclose(back.unwrapped()[:, 0, 0], 9.5 + np.arange(30) * 0.05, atol=2e-6)
    with pytest.raises(ValueError, match=r"period must be a length in \[0, .*got -1"):
        Trajectories.from_csv(tmp_path / "t.csv", fps=25, period=-1)
    # 9.9999999 m is written as 10.000000: the seam itself is on the axis, past it is not
    (tmp_path / "e.csv").write_text("frame,id,x,y\n0,1,10.000000,3\n1,1,0.05,3\n")
    assert Trajectories.from_csv(tmp_path / "e.csv", fps=25, period=10.0).n_steps == 2
    with pytest.raises(ValueError, match=r"e.csv:2: x = 10 m lies outside .*\[0, 9\.5\] m"):
        Trajectories.from_csv(tmp_path / "e.csv", fps=25, period=9.5)


def test_a_person_absent_for_a_row_while_crossing_the_seam_keeps_heading():
    """A gap (a row missing from a CSV) across the seam: the next present row goes on past
    the seam from the last present one, so the heading stays 0 (it had jumped back by a
    period there, and the heading turned round for the frames whose window spans the gap)."""
    pos = np.zeros((30, 1, 2))
    pos[:, 0, 0] = (9.5 + np.arange(30) * 0.05) % 10.0
    pos[:, 0, 1] = 3.0
    pos[10, 0] = np.nan  # absent at x = 10.0, on the seam
    pos[12:14, 0] = np.nan  # and again just past it
    traj = Trajectories(positions=pos, ids=np.arange(1), dt=0.04, meta={"period": 10})
    want = 9.5 + np.arange(30) * 0.05
    want[10] = want[12] = want[13] = np.nan
    np.testing.assert_allclose(traj.unwrapped()[:, 0, 0], want)
    heading = prepare_agents(traj, CAMERA, AppearanceParams(sway_deg=0.0), 0).heading
    np.testing.assert_allclose(heading, 0, atol=1e-9)


def test_prominent_attribute_gets_distinct_colours():
    traj = walkers(2)
    tracks = prepare_agents(traj, CAMERA, PARAMS, seed=0)
    n_var = PARAMS.n_clusters * PARAMS.variants_per_cluster
    np.testing.assert_array_equal(tracks.appearance >= n_var, traj.attributes["prominent"])


@pytest.mark.parametrize(
    "points",
    [
        np.zeros((0, 2)),  # empty crowd
        np.array([[np.nan, np.nan]]),  # absent agent
        np.array([[-3.0, 5.0], [255.5, 175.5], [1e6, -1e6]]),  # partly and far outside
    ],
)
def test_edge_cases_render_without_error(points):
    r = SceneRenderer(CAMERA, PARAMS, seed=0, fps=25.0)
    frame = r.render(0, points, np.zeros(len(points)), np.zeros(len(points), int))
    assert frame.shape == (176, 256, 3)


@pytest.mark.parametrize(
    ("pixels", "heading", "appearance", "pose", "message"),
    [
        ([[50.0, 50.0]], [0.0], [10**6], None, "appearance must be in [0, "),
        ([[50.0, 50.0]], [0.0], [-1], None, "appearance must be in [0, "),
        ([[50.0, 50.0]], [0.0], [0.5], None, "appearance must hold integer indices, got 0.5"),
        ([[50.0, 50.0]], [0.0], [0], [99], "pose must be in [0, "),
        ([[50.0, 50.0, 1.0]], [0.0], [0], None, "pixels must have shape (n, 2), got (1, 3)"),
        ([[50.0, 50.0]], [0.0, 1.0], [0], None, "heading must have shape (1,), got (2,)"),
        ([[50.0, 50.0]], [0.0], [0, 1], None, "appearance must have shape (1,), got (2,)"),
    ],
)
def test_bad_agent_arrays_are_refused_by_name(pixels, heading, appearance, pose, message):
    """An appearance index outside the sprite bank had crashed the interpreter (the compiled
    stamp read past the colour table: SIGSEGV); the other arrays failed deep in numpy."""
    import re

    r = SceneRenderer(CAMERA, PARAMS, seed=0, fps=25.0)
    with pytest.raises(ValueError, match=re.escape(message)):
        r.render(0, np.array(pixels), np.array(heading), np.array(appearance), pose=pose)
    # an absent agent's index is never read, so it is not checked
    frame = r.render(0, np.array([[np.nan, np.nan]]), np.zeros(1), np.array([10**6]))
    assert frame.shape == (176, 256, 3)
    # whole numbers in a float array (a column read from a file) draw as the integers do
    pts = np.array([[50.0, 50.0], [80.0, 60.0], [np.nan, np.nan]])
    as_int = r.render(0, pts, np.zeros(3), np.array([1, 2, 0]))
    np.testing.assert_array_equal(
        r.render(0, pts, np.zeros(3), np.array([1.0, 2.0, np.nan])), as_int
    )


def _bilinear(image: np.ndarray, y: float, x: float, h: int, w: int) -> np.ndarray:
    """``image`` sampled at ``(y + r, x + c)`` for the ``h x w`` grid of rows ``r`` and
    columns ``c`` (bilinear, float)."""
    y0, x0 = int(np.floor(y)), int(np.floor(x))
    fy, fx = y - y0, x - x0
    g = image.astype(np.float64)[y0 : y0 + h + 1, x0 : x0 + w + 1]
    return (
        (1 - fy) * (1 - fx) * g[:h, :w]
        + (1 - fy) * fx * g[:h, 1:]
        + fy * (1 - fx) * g[1:, :w]
        + fy * fx * g[1:, 1:]
    )


def test_jitter_moves_ground_and_people_together():
    """Frame pixel ``p`` shows the ground at ``p + margin - jitter``: the ground moves by the
    same sub-pixel offset as the people (whose pixels, the ground truth, carry the jitter), not
    by the offset rounded to whole pixels (up to 0.5 px apart before)."""
    cam = Camera(px_per_m=24.0, width=128, height=96, center=(0.0, 0.0), jitter_px=3.0, seed=2)
    params = AppearanceParams(
        template_px=12, noise_sigma=0.0, illumination_drift=0.0, ground_texture=20.0
    )
    r = SceneRenderer(cam, params, seed=0, fps=25.0)
    none = (np.zeros((0, 2)), np.zeros(0), np.zeros(0, int))
    offsets = cam.jitter(30)
    frac = np.abs(offsets - np.rint(offsets))
    assert frac.max() > 0.3  # frames between whole pixels are checked
    m = r.margin
    for t in range(30):
        frame = r.render(t, *none).astype(float)
        want = _bilinear(r.ground, m - offsets[t, 1], m - offsets[t, 0], 96, 128)
        # the kernel rounds once, the reference not at all
        np.testing.assert_allclose(frame, want, atol=0.5 + 1e-3, err_msg=f"frame {t}")


def test_camera_shake_moves_people_but_does_not_turn_them():
    """Facing comes from the walk on the ground, not from the shaken pixels: once, seq6's
    2.3 px shake turned its slow runners frame by frame (BQP lost 18 points at 15 px)."""
    from dataclasses import replace

    traj = walkers(24)
    still = prepare_agents(traj, CAMERA, PARAMS, seed=0)
    shaken = prepare_agents(traj, replace(CAMERA, jitter_px=4.0, jitter_frames=1.0), PARAMS, 0)
    np.testing.assert_array_equal(shaken.heading, still.heading)
    np.testing.assert_array_equal(shaken.pose, still.pose)
    moved = shaken.pixels - still.pixels
    assert np.nanmax(np.abs(moved)) > 2  # the people do move with the camera


def test_a_still_camera_with_the_shakes_ground_margin_draws_the_shaken_scene_unshaken():
    """``crowdsim difficulty``'s still twin of a shaken spec: with the shaken camera's ground
    margin it draws the very frames the shaken camera would with its shake at zero (same
    ground, clutter, people, light and noise); with its own, smaller margin, other ground."""
    from dataclasses import replace

    from crowdsim.camera import shake_margin

    params = replace(PARAMS, distractor_density=0.05, moving_shadow_density=0.02)
    shaken = replace(CAMERA, jitter_px=2.5, seed=4)
    margin = shake_margin(2.5)
    assert shaken.ground_margin == margin == 11
    twin = replace(CAMERA, seed=4, ground_margin_px=margin)
    assert twin.ground_margin == margin and not twin.moves
    tracks = prepare_agents(walkers(6), twin, params, seed=1)
    r_shaken = SceneRenderer(shaken, params, seed=5, fps=25.0)
    r_shaken._frame_jitter = lambda t: np.zeros(2)  # the shaken camera, held still
    r_twin = SceneRenderer(twin, params, seed=5, fps=25.0)
    r_own = SceneRenderer(replace(CAMERA, seed=4), params, seed=5, fps=25.0)
    np.testing.assert_array_equal(r_twin.ground, r_shaken.ground)
    for t in range(6):
        args = (t, tracks.pixels[t], tracks.heading[t], tracks.appearance)
        frame = r_twin.render(*args, pose=tracks.pose[t])
        np.testing.assert_array_equal(frame, r_shaken.render(*args, pose=tracks.pose[t]))
        assert np.abs(frame.astype(int) - r_own.render(*args, pose=tracks.pose[t])).max() > 20


def test_gt_rows_are_head_boxes_inside_the_frame():
    traj = walkers(3)
    tracks = prepare_agents(traj, CAMERA, PARAMS, seed=0)
    tracks.pixels[0, 0] = (-1.0, 10.0)  # head outside: no row
    tracks.pixels[0, 1] = (2.0, 10.0)  # head inside, box partly outside
    rows = gt_rows(tracks.pixels, CAMERA, 12, mot_ids(tracks.ids))
    assert rows.shape[1] == 9
    assert not ((rows[:, 0] == 1) & (rows[:, 1] == 11)).any()
    r = rows[(rows[:, 0] == 1) & (rows[:, 1] == 12)][0]
    np.testing.assert_allclose(r[2:6], [-4.0, 4.0, 12.0, 12.0])
    assert r[8] == pytest.approx(8 / 12)
    assert (np.diff(rows[:, 0]) >= 0).all()


def test_sprite_bank_is_anti_aliased_and_centred():
    p = AppearanceParams(template_px=12, subpixel=2, orientation_bins=8, shadow=0.0)
    bank = build_sprite_bank(p, np.random.default_rng(0))
    z = bank.size
    assert bank.alpha.shape == (p.n_poses * 8 * 4, z, z)
    assert bank.cover.shape == (p.n_poses * 8 * 4, z, z, 3)
    assert bank.colours.shape == (p.n_appearances, 3, 3)
    lo, hi = bank.spans[..., 0], bank.spans[..., 1]
    cols = np.arange(z)
    inside = (cols >= lo[..., None]) & (cols < hi[..., None])
    assert not bank.alpha[~inside].any()  # spans cover every drawn pixel
    assert 0.0 <= bank.alpha.min() and bank.alpha.max() <= 1.0 + 1e-6
    assert ((bank.alpha > 0.05) & (bank.alpha < 0.95)).any()  # soft edges
    idx = bank.index(np.array([0]), np.array([0]), np.array([0]), np.array([0]))[0]
    a = bank.alpha[idx]
    yy, xx = np.mgrid[0:z, 0:z]
    centre = (z - 1) / 2
    assert abs((a * yy).sum() / a.sum() - centre) < 0.1  # symmetric across the walking axis


def test_parallel_bands_give_the_same_frame_as_one_band(monkeypatch):
    import crowdsim.render as render_mod

    rng = np.random.default_rng(3)
    n = 400  # heavy overlap: many sprites straddle band borders
    pts = rng.uniform(-5, [261, 181], (n, 2))
    hd = rng.uniform(-math.pi, math.pi, n)
    app = rng.integers(0, PARAMS.n_appearances, n)
    r = SceneRenderer(CAMERA, PARAMS, seed=0, fps=25.0)
    many = r.render(2, pts, hd, app).copy()
    monkeypatch.setattr(render_mod, "STAMP_BANDS", 1)
    np.testing.assert_array_equal(r.render(2, pts, hd, app), many)


def test_illumination_drifts_and_motion_blur_smooths():
    cam = Camera(px_per_m=24.0, width=96, height=64)
    none = (np.zeros((0, 2)), np.zeros(0), np.zeros(0, int))
    lit = AppearanceParams(illumination_drift=0.2, illumination_period_s=1.0, noise_sigma=0.0)
    r = SceneRenderer(cam, lit, seed=0, fps=25.0)
    means = [r.render(t, *none).mean() for t in range(25)]
    assert max(means) / min(means) > 1.15  # +-20 % over one period
    flat = SceneRenderer(
        cam, AppearanceParams(illumination_drift=0.0, noise_sigma=0.0), seed=0, fps=25.0
    )
    assert np.ptp([flat.render(t, *none).mean() for t in range(5)]) < 1e-9
    sharp = SceneRenderer(cam, AppearanceParams(ground_texture=30.0), seed=0, fps=25.0)
    blurred = SceneRenderer(
        cam, AppearanceParams(ground_texture=30.0, motion_blur_px=7.0), seed=0, fps=25.0
    )
    a, b = sharp.render(0, *none), blurred.render(0, *none)
    assert (
        np.abs(np.diff(b.astype(float), axis=1)).mean()
        < 0.7 * np.abs(np.diff(a.astype(float), axis=1)).mean()
    )
    np.testing.assert_array_equal(b, blurred.render(0, *none))


def test_overwrite_checks_ownership_again_before_the_swap(tmp_path):
    """A file the user adds to the old sequence while the new one renders (minutes, for a
    long one) survives: the swap checks again and refuses, naming it, and leaves no
    temporary folder. So does a folder that appears meanwhile without ``overwrite``."""
    from synth_data.writer import TMP_PREFIX

    traj = walkers(n_frames=4)
    out = tmp_path / "seq"
    write_sequence(out, traj, camera=CAMERA, appearance=PARAMS, seed=3)
    mine = out / "gt" / "my_labels.txt"

    def user_writes(_):
        mine.write_text("mine")

    with pytest.raises(ValueError, match=f"{mine} was not written by crowdsim"):
        write_sequence(
            out,
            traj,
            camera=CAMERA,
            appearance=PARAMS,
            seed=3,
            overwrite=True,
            progress=user_writes,
        )
    assert mine.read_text() == "mine"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["seq"]
    late = tmp_path / "late"

    def user_makes(_):
        late.mkdir(exist_ok=True)
        (late / "notes.txt").write_text("mine")

    with pytest.raises(FileExistsError, match="late already exists"):
        write_sequence(late, traj, camera=CAMERA, appearance=PARAMS, seed=3, progress=user_makes)
    assert sorted(p.name for p in late.iterdir()) == ["notes.txt"]
    assert not list(tmp_path.glob(f"{TMP_PREFIX}*"))


@pytest.mark.parametrize(
    ("args", "message"),
    [(("--frames", "0"), "--frames must be in [1, 10000], got 0"), (("--only", "seq99"), "seq99")],
)
def test_ground_sharpness_benchmark_names_bad_flags(run_benchmark, args, message):
    out = run_benchmark("ground_sharpness.py", *args)
    assert out.returncode == 2 and message in out.stderr and "Traceback" not in out.stderr


def test_headings_before_the_first_move_are_back_filled():
    """Headings before an agent's first move are back-filled, not random."""
    t = np.arange(6, dtype=np.float64)
    pixels = np.stack([np.full(6, 10.0), 5.0 + 2.0 * t], axis=1)[:, None, :]  # walks +v (down)
    speed_ok = np.array([False, False, True, True, True, True])[:, None]
    out = _headings(pixels, speed_ok, np.random.default_rng(0))
    np.testing.assert_allclose(out[:, 0], np.full(6, math.pi / 2))


def test_prominent_agents_get_a_prominent_look_and_the_rest_a_cluster_variant():
    """Prominent agents get the prominent looks (indices from n_var on), others below."""
    params = AppearanceParams()
    n_var = params.n_clusters * params.variants_per_cluster
    prominent = np.arange(400) % 2 == 0
    app, prom = assign_appearance(prominent, 400, params, np.random.default_rng(3))
    np.testing.assert_array_equal(prom, prominent)
    assert (app[prominent] >= n_var).all()
    assert (app[prominent] < n_var + len(PROMINENT_COLOURS)).all()
    assert set(app[prominent].tolist()) == set(range(n_var, n_var + len(PROMINENT_COLOURS)))
    assert (app[~prominent] < n_var).all() and (app[~prominent] >= 0).all()


def test_clothing_contrast_scales_colours_about_the_ground():
    """Contrast c maps a clothing colour x to ground + c (x - ground)."""
    full = appearance_colours(AppearanceParams(), np.random.default_rng(0))
    half = appearance_colours(AppearanceParams(contrast=0.5), np.random.default_rng(0))
    ground = np.array(AppearanceParams().ground_bgr, np.float64)
    np.testing.assert_allclose(half, ground + 0.5 * (np.clip(full, 0, 255) - ground), atol=1e-9)
    assert np.abs(half - ground).max() < np.abs(full - ground).max()


def test_moving_shadows_wrap_over_the_frame_plus_one_mask():
    """Moving shadows wrap over [-S, W) x [-S, H), reaching the right and bottom edges."""
    cam = Camera(px_per_m=10.0, width=64, height=48)
    params = AppearanceParams(moving_shadow_density=0.5)
    r = SceneRenderer(cam, params, seed=1, fps=25.0)
    size = int(math.ceil(2.0 * params.moving_shadow_m * cam.px_per_m)) + 3
    corners = np.stack([r.moving_shadow_corners(t) for t in range(0, 2000, 5)])
    assert corners.shape[1] > 3
    x, y = corners[..., 0], corners[..., 1]
    assert x.min() >= -size and x.max() <= 63 and y.min() >= -size and y.max() <= 47
    assert x.max() >= 62 and y.max() >= 46
