"""The numba force kernel against a direct O(n²) transcription of the equations."""

from __future__ import annotations

import math

import numpy as np
import pytest

from crowdsim.forces import (
    BodyRows,
    WallGrid,
    contact_space,
    group_vision_attraction,
    social_force,
)
from crowdsim.params import SocialForceParams
from crowdsim.world import polyline, rectangle


def reference_hm95(pos, vel, e, v0, walls, p: SocialForceParams, period=0.0) -> np.ndarray:
    """Helbing & Molnár (1995) Eqs. 2-8 written pair by pair (no headway, no cap, no groups);
    with ``period``, x is periodic and each pair interacts across the nearer way round."""
    n = len(pos)
    acc = (v0[:, None] * e - vel) / p.tau
    cos_phi = math.cos(math.radians(p.fov_deg / 2))
    for i in range(n):
        for j in range(n):
            if i == j:
                continue
            r = pos[i] - pos[j]
            if period:
                r[0] -= period * round(r[0] / period)
            d = np.linalg.norm(r)
            if d >= p.cutoff:
                continue
            s = vel[j] * p.step_time
            q = r - s
            dq = np.linalg.norm(q)
            b = 0.5 * math.sqrt(max((d + dq) ** 2 - s @ s, 1e-12))
            b = max(b, p.b_min)
            grad_b = (d + dq) / (4 * b) * (r / d + q / dq)
            f = p.V0 / p.sigma * math.exp(-b / p.sigma) * grad_b
            seen = e[i] @ (-r) >= d * cos_phi
            acc[i] += f if seen else p.c * f
        for x0, y0, x1, y1, th in walls:
            a, u = np.array([x0, y0]), np.array([x1 - x0, y1 - y0])
            t = np.clip((pos[i] - a) @ u / (u @ u), 0, 1)
            r = pos[i] - (a + t * u)
            dc = np.linalg.norm(r)
            if dc < p.cutoff + th:
                acc[i] += p.U0 / p.R * math.exp(-max(dc - th, 0) / p.R) * r / dc
    return acc


@pytest.mark.parametrize("seed", range(5))
def test_kernel_matches_pairwise_reference(seed):
    rng = np.random.default_rng(seed)
    n = 40
    pos = rng.uniform(0.5, 5.5, (n, 2))
    vel = rng.normal(0, 0.8, (n, 2))
    ang = rng.uniform(0, 2 * np.pi, n)
    e = np.column_stack([np.cos(ang), np.sin(ang)])
    v0 = rng.uniform(0.8, 1.6, n)
    walls = np.vstack([rectangle(0, 0, 6, 6), polyline([(2.0, 3.0), (4.0, 3.5)], 0.1)])
    p = SocialForceParams(headway_time=0.0, speed_cap=1000.0)
    got = social_force(pos, vel, np.full(n, 0.22), v0, e, np.full(n, -1), walls, p)
    want = reference_hm95(pos, vel, e, v0, walls, p)
    np.testing.assert_allclose(got, want, rtol=1e-9, atol=1e-9)


@pytest.mark.parametrize("seed", range(3))
def test_kernel_matches_pairwise_reference_across_a_periodic_seam(seed):
    """A periodic corridor short enough that most pairs near the seam interact only the
    short way round: the kernel's ghosts must give the minimum-image forces."""
    rng = np.random.default_rng(seed)
    p = SocialForceParams(headway_time=0.0, speed_cap=1000.0)
    period = 3.0 * p.cutoff + 0.5
    n = 40
    pos = np.column_stack([rng.uniform(0, period, n), rng.uniform(0.5, 3.5, n)])
    pos[:4, 0] = [0.05, period - 0.05, 0.3, period - 0.4]  # pairs straddling the seam
    vel = rng.normal(0, 0.8, (n, 2))
    ang = rng.uniform(0, 2 * np.pi, n)
    e = np.column_stack([np.cos(ang), np.sin(ang)])
    v0 = rng.uniform(0.8, 1.6, n)
    walls = np.zeros((0, 5))
    got = social_force(pos, vel, np.full(n, 0.22), v0, e, np.full(n, -1), walls, p, period=period)
    want = reference_hm95(pos, vel, e, v0, walls, p, period=period)
    np.testing.assert_allclose(got, want, rtol=1e-9, atol=1e-9)
    flat = reference_hm95(pos, vel, e, v0, walls, p)
    assert np.abs(flat[:4] - want[:4]).max() > 0.1  # the seam pairs do interact across it


def test_wall_grid_gives_the_same_forces_as_one_cell_with_every_wall():
    rng = np.random.default_rng(3)
    # A hall with many pillars: the grid must not drop any wall within reach.
    walls = [rectangle(0, 0, 40, 40)]
    for x in range(4, 40, 4):
        for y in range(4, 40, 4):
            walls.append(rectangle(x - 0.4, y - 0.4, x + 0.4, y + 0.4))
    walls = np.vstack(walls)
    n = 500
    pos = rng.uniform(0.3, 39.7, (n, 2))
    vel = rng.normal(0, 0.5, (n, 2))
    e = np.tile([1.0, 0.0], (n, 1))
    args = (
        pos,
        vel,
        np.full(n, 0.2),
        np.full(n, 1.3),
        e,
        np.full(n, -1),
        walls,
        SocialForceParams(),
    )
    binned = social_force(*args, wall_grid=WallGrid(walls, 1.5))
    one_cell = social_force(*args, wall_grid=WallGrid(walls, 1.5, cell=200.0))
    np.testing.assert_array_equal(binned, one_cell)


def test_a_wall_grid_too_large_for_memory_is_refused_with_its_size():
    wall = np.array([[0.0, 0.0, 1e9, 0.0, 0.05], [0.0, 0.0, 0.0, 1e9, 0.05]])
    with pytest.raises(
        ValueError,
        match=r"the walls' grid \(666666669 x 666666669 cells of "
        r"1.5 m over a world of 1e\+09 x 1e\+09 m\) needs about .* PiB",
    ):
        WallGrid(wall, 1.5)
    grid = WallGrid(wall[:1] / 1e6, 1.5)  # 1 km: 669 cells of 1.5 m along it
    assert grid.params[3:].tolist() == [669.0, 3.0]


def test_headway_caps_speed_behind_a_standing_body():
    """A walker behind a standing person may not exceed (v0 / v_ref) gap / T."""
    p = SocialForceParams()
    pos = np.array([[0.0, 0.0], [0.75, 0.0]])
    vel = np.array([[1.0, 0.0], [0.0, 0.0]])
    e = np.array([[1.0, 0.0], [1.0, 0.0]])
    r = np.array([0.22, 0.22])
    acc = social_force(
        pos, vel, r, np.array([1.3, 0.0]), e, np.array([-1, -1]), np.zeros((0, 5)), p
    )
    gap = 0.75 - p.headway_depth * 0.44
    v_next = np.hypot(*(vel[0] + acc[0] * p.dt))
    assert v_next == pytest.approx(1.3 / p.headway_ref_speed * gap / p.headway_time, rel=1e-9)


def test_no_agents_no_walls():
    p = SocialForceParams()
    out = social_force(
        np.zeros((0, 2)),
        np.zeros((0, 2)),
        np.zeros(0),
        np.zeros(0),
        np.zeros((0, 2)),
        np.zeros(0, np.int64),
        np.zeros((0, 5)),
        p,
    )
    assert out.shape == (0, 2)


CACHE_PROBE = """
import json
import numpy as np
from crowdsim import forces
from crowdsim.params import SocialForceParams

def crowd(n):
    side = int(np.ceil(np.sqrt(n)))
    xy = np.stack(np.meshgrid(np.arange(side), np.arange(side)), -1).reshape(-1, 2)[:n] * 0.8
    e = np.tile([1.0, 0.0], (n, 1))
    return xy.astype(float), np.zeros((n, 2)), np.full(n, 0.22), np.full(n, 1.3), e, np.full(n, -1)

walls = np.zeros((0, 5))
forces.social_force(*crowd(50), walls, SocialForceParams())  # the serial kernel
forces.social_force(*crowd(forces.PARALLEL_MIN_AGENTS), walls, SocialForceParams())
print(json.dumps({
    name: sum(getattr(kernel.stats, "cache_" + what).values())
    for kernel, tag in ((forces._kernel_serial, "serial"), (forces._kernel_parallel, "parallel"))
    for what in ("hits", "misses")
    for name in [tag + "_" + what]
}))
"""


def test_serial_and_parallel_kernels_keep_their_own_cache_entries(tmp_path):
    """numba keys its disk cache by function name and signature, not by ``parallel``: were
    the two kernels one function's two wrappings, the parallel one would load the serial
    one's machine code (cached first here) and run on one thread in every later process."""
    import json
    import os
    import subprocess
    import sys

    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path)}
    run = [sys.executable, "-c", CACHE_PROBE]
    first = json.loads(subprocess.run(run, env=env, capture_output=True, check=True).stdout)
    # a fresh cache: the parallel kernel finds no entry of the serial one's, compiles its own
    assert first == {"serial_hits": 0, "serial_misses": 1, "parallel_hits": 0, "parallel_misses": 1}
    again = json.loads(subprocess.run(run, env=env, capture_output=True, check=True).stdout)
    assert again == {"serial_hits": 1, "serial_misses": 0, "parallel_hits": 1, "parallel_misses": 0}


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--threads", "0"], "--threads must be in [1, "),
        (["--agents", "0"], "--agents and --repeats must be >= 1"),
    ],
)
def test_force_threads_benchmark_names_bad_flags(run_benchmark, args, message):
    out = run_benchmark("force_threads.py", *args)
    assert out.returncode == 2 and message in out.stderr and "Traceback" not in out.stderr


def test_force_threads_benchmark_times_each_count(run_benchmark):
    import json

    out = run_benchmark("force_threads.py", "--threads", "1", "--agents", "6000", "--repeats", "1")
    assert out.returncode == 0, out.stderr
    report = json.loads(out.stdout.strip().splitlines()[-1])
    assert report["agents"] == 6000 and list(report["ms"]) == ["1"] and report["ms"]["1"] > 0


def test_body_rows_count_the_walls_static_body_and_refuse_a_short_write():
    """Once a wall hangs on the space's static body, pymunk's batch API iterates that body
    too: n agents between walls are n + 1 rows. The split workers wrote n, and pymunk read the
    static body's row from past the array's end, so whatever the heap held there became the
    walls' velocity (2-worker runs of one seed differed from the first step, depending on the
    worker's memory). A short write is now refused, naming the counts."""
    import pymunk
    import pymunk.batch as pb

    walls = np.array([[0.0, 0.0, 10.0, 0.0, 0.05]])
    space = contact_space(SocialForceParams(), walls)
    for x in (1.0, 2.0, 3.0):
        body = pymunk.Body(80.0, float("inf"))
        body.position = (x, 1.0)
        space.add(body, pymunk.Circle(body, 0.25))
    io = BodyRows(space)
    fields = pb.BodyFields.POSITION | pb.BodyFields.VELOCITY
    rows = io.read(fields).copy()
    assert rows.shape == (4, 4)  # three agents and the static body, at rest at the origin
    static = io.read_ids() == space.static_body.id
    assert static.sum() == 1 and (rows[static] == 0).all()
    with pytest.raises(ValueError, match=r"BodyRows.write: 3 rows for the 4 bodies"):
        io.write(fields, rows[~static])
    rows[~static, 2] = 1.0
    io.write(fields, rows)
    assert space.static_body.velocity == (0.0, 0.0)
    assert [b.velocity.x for b in space.bodies] == [1.0, 1.0, 1.0]


def test_exponential_potential_repels_by_the_sum_of_the_radii():
    """``potential="exponential"``: ``A exp((r_i + r_j - d) / B)`` along the line between two
    people who see each other (hand-computed; no driving, wall or group force)."""
    p = SocialForceParams(potential="exponential", headway_time=0.0, speed_cap=1000.0)
    pos = np.array([[0.0, 0.0], [1.0, 0.0]])
    facing = np.array([[1.0, 0.0], [-1.0, 0.0]])
    radius = np.array([0.3, 0.2])
    acc = social_force(
        pos, np.zeros((2, 2)), radius, np.zeros(2), facing, np.array([-1, -1]), np.zeros((0, 5)), p
    )
    w = p.A * math.exp((0.3 + 0.2 - 1.0) / p.B)
    np.testing.assert_allclose(acc, [[-w, 0.0], [w, 0.0]], rtol=1e-12)


def test_group_members_closer_than_the_gap_repel_by_beta3():
    """[M10] f_rep: two members of one group standing closer than ``r_i + r_j + gap`` are
    pushed apart by ``beta3`` along the line between them (hand-computed: at rest, so the
    vision term ``-beta1 alpha v`` is 0, and 0.3 m from their centre, within ``(N - 1) / 2 =
    0.5`` m, so there is no attraction); beyond the gap the group changes nothing."""
    p = SocialForceParams(headway_time=0.0, speed_cap=1000.0, beta3=0.7)
    r = np.array([0.22, 0.22])
    e = np.array([[0.0, 1.0], [0.0, 1.0]])
    none = np.zeros((0, 5))

    def acc(d, group):
        pos = np.array([[0.0, 0.0], [d, 0.0]])
        return social_force(pos, np.zeros((2, 2)), r, np.zeros(2), e, group, none, p)

    close = acc(0.6, np.array([4, 4])) - acc(0.6, np.array([-1, -1]))
    np.testing.assert_allclose(close, [[-0.7, 0.0], [0.7, 0.0]], atol=1e-12)
    apart = acc(0.8, np.array([4, 4])) - acc(0.8, np.array([-1, -1]))  # 0.8 > 0.74
    np.testing.assert_allclose(apart, 0.0, atol=1e-12)


def test_group_vision_and_attraction_by_hand():
    """[M10] vision ``-beta1 alpha v`` with ``alpha`` the turn past ``group_gaze_deg`` needed
    to see the group's centre, and attraction ``beta2`` towards the centre beyond ``(N - 1)
    / 2`` m from it."""
    p = SocialForceParams(beta1=0.5, beta2=2.0, group_gaze_deg=90.0)
    # a pair 1.6 m apart (0.8 m > 0.5 m from the centre), both walking +x at 1 m/s: the
    # leader (x = 1.6) has the centre straight behind it (alpha = 180 - 90 degrees), the
    # follower straight ahead (alpha = 0); a lone walker gets nothing
    pos = np.array([[0.0, 0.0], [1.6, 0.0], [5.0, 5.0]])
    vel = np.array([[1.0, 0.0], [1.0, 0.0], [1.0, 0.0]])
    e = np.array([[1.0, 0.0]] * 3)
    f = group_vision_attraction(pos, vel, e, np.array([3, 3, -1]), p)
    np.testing.assert_allclose(
        f, [[2.0, 0.0], [-0.5 * math.pi / 2 - 2.0, 0.0], [0.0, 0.0]], atol=1e-12
    )
    # 0.4 m from the centre: within (2 - 1) / 2 m, no attraction; vision as before
    near = group_vision_attraction(pos * 0.5, vel, e, np.array([3, 3, -1]), p)
    np.testing.assert_allclose(
        near, [[0.0, 0.0], [-0.5 * math.pi / 2, 0.0], [0.0, 0.0]], atol=1e-12
    )


@pytest.mark.parametrize(
    ("heading_deg", "follows"), [(0.0, True), (45.0, True), (90.0, False), (180.0, False)]
)
def test_headway_follows_only_a_body_that_heads_within_60_degrees(heading_deg, follows):
    """The headway cap applies behind a body whose direction is within 60 degrees of the
    walker's (``e_i . e_j > 0.5``): 0 and 45 degrees give the cap of the test above; a body
    crossing (90) or coming towards the walker (180) leaves the speed to the forces alone, the
    same as with ``headway_time = 0``."""
    p = SocialForceParams()
    pos = np.array([[0.0, 0.0], [0.75, 0.0]])
    vel = np.array([[1.0, 0.0], [0.0, 0.0]])
    a = math.radians(heading_deg)
    e = np.array([[1.0, 0.0], [math.cos(a), math.sin(a)]])
    r = np.array([0.22, 0.22])
    args = (pos, vel, r, np.array([1.3, 0.0]), e, np.array([-1, -1]), np.zeros((0, 5)))
    acc = social_force(*args, p)
    v_next = np.hypot(*(vel[0] + acc[0] * p.dt))
    capped = 1.3 / p.headway_ref_speed * (0.75 - p.headway_depth * 0.44) / p.headway_time
    free = social_force(*args, SocialForceParams(headway_time=0.0))
    if follows:
        assert v_next == pytest.approx(capped, rel=1e-9)
    else:
        np.testing.assert_array_equal(acc[0], free[0])
        assert v_next > 1.5 * capped
