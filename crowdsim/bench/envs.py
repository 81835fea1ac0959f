"""``crowdsim bench envs``: speed of the environments in :mod:`envs` (issue 9, "Speed").

One function per section, each returning a JSON-ready dict; ``--only`` picks sections
(default: all). The output is a table per section and one JSON object (last line).

Sections
--------
``crowd``
    ``envs.crowd_v0`` with ``--agents`` pedestrians (default 1,000), all of them agents, in
    a periodic counterflow corridor at 1 /m² (nobody leaves, so the count stays fixed):
    env steps per second through the array API (:meth:`~envs.crowd.CrowdParallelEnv.
    step_arrays`, seeded uniform actions in ``[-vmax, vmax]^2``) and through the
    per-agent dict API (:meth:`~envs.crowd.CrowdParallelEnv.step` with a prepared action
    dict), beside the bare simulation step under the same control (what the env adds is
    observations, rewards and book-keeping). ``--warmup`` untimed steps, then ``--steps``
    timed ones, each API from the same seed; ``--repeat`` rounds, the best counts. Target:
    >= 200 steps/s through the array API at 1,000 agents (issue 9).
``tuning``
    ``crowdsim/TrackerTuning-v0`` (the real BQP tracker, ``--k`` frames per step) on
    counterflow crowds of ``--targets`` people (default 100 and 300; frames up to 1280x720,
    12 px heads): a pool of ``--episodes`` episodes of ``--frames`` frames, each run from reset
    to its end, env steps/s with resets counted -- first rendering each episode at its reset
    (simulation, rendering, H.264 and JPEG), then reading it from the episode cache
    (:class:`envs.episodes.EpisodeCache`, filled first and timed apart); "step only" is the
    rate without the resets (tracking alone). ``--repeat`` rounds, rendered and cached in
    turn, the best of each counts. Then ``--workers`` asynchronous envs
    (Gymnasium ``AsyncVectorEnv``, ``spawn``, the first crowd size), with and without the
    cache: env steps/s over the vector against one env.
"""

from __future__ import annotations

import argparse
import json
import time
from collections.abc import Callable
from statistics import median
from typing import Any

import numpy as np

from crowdsim.atomic import OVERWRITE_HELP

CROWD_TARGET_STEPS_PER_S = 200.0


def _timed(step: Callable[[int], Any], warmup: int, steps: int) -> float:
    """Wall seconds of ``steps`` calls ``step(k)`` after ``warmup`` untimed ones."""
    for k in range(warmup):
        step(k)
    t0 = time.perf_counter()
    for k in range(steps):
        step(warmup + k)
    return time.perf_counter() - t0


# ------------------------------------------------------------------------------ crowd_v0


def bench_crowd(
    agents: int = 1000, steps: int = 200, warmup: int = 20, seed: int = 0, repeat: int = 3
) -> dict[str, Any]:
    """crowd_v0 steps/s through the array API, the dict API and the bare simulation.

    Each of ``repeat`` rounds times the three in turn, each on a fresh env reset from
    ``seed``; the best round counts (timeit's rule: on a shared machine the fastest run is
    the least disturbed one), the median is reported beside it.
    """
    from envs.crowd import CrowdParallelEnv

    kwargs = {
        "n_agents": agents,
        "max_cycles": steps + warmup + 1,
        "scenario_params": {"periodic": True, "inflow": False},
    }
    rng = np.random.default_rng(seed)
    env = CrowdParallelEnv(**kwargs)
    actions = rng.uniform(-env.params.vmax, env.params.vmax, (steps + warmup, agents, 2))
    names = [f"ped_{i}" for i in range(agents)]
    # The agent set stays fixed in the periodic corridor; dicts are built before timing.
    act_dicts = [
        dict(zip(names, actions[k].astype(np.float32), strict=True)) for k in range(steps + warmup)
    ]

    def arrays() -> float:
        env.reset_arrays(seed)
        return _timed(lambda k: env.step_arrays(actions[k]), warmup, steps)

    def per_agent() -> float:
        env.reset(seed=seed)
        return _timed(lambda k: env.step(act_dicts[k]), warmup, steps)

    def simulation() -> float:
        env.reset_arrays(seed)
        sim, ids = env.sim, env.agent_ids
        return _timed(
            lambda k: sim.step(desired_velocity=actions[k], controlled=ids), warmup, steps
        )

    walls: dict[str, list[float]] = {"arrays": [], "dict": [], "simulation": []}
    for _ in range(repeat):
        for api, fn in (("arrays", arrays), ("dict", per_agent), ("simulation", simulation)):
            walls[api].append(fn())
            if env.sim.state.n != agents:
                raise RuntimeError(
                    "agents left the periodic corridor; the benchmark needs a fixed count"
                )
    rows = []
    for api, times in walls.items():
        best = min(times)
        rows.append(
            {
                "api": api,
                "agents": agents,
                "steps": steps,
                "wall_s": best,
                "steps_per_s": steps / best,
                "median_steps_per_s": steps / median(times),
                "agent_steps_per_s": steps * agents / best,
            }
        )
    return {
        "scenario": "counterflow periodic, 1 /m2, 6 m wide",
        "warmup_steps": warmup,
        "repeat": repeat,
        "obs_size": env.params.obs_size,
        "results": rows,
        "target_steps_per_s": CROWD_TARGET_STEPS_PER_S,
        "meets_target": rows[0]["steps_per_s"] >= CROWD_TARGET_STEPS_PER_S,
    }


def _print_crowd(report: dict[str, Any]) -> None:
    print(f"crowd_v0 ({report['scenario']}, obs size {report['obs_size']})")
    head = (
        f"{'api':<12} {'agents':>7} {'steps':>6} {'steps/s':>9} {'median':>8} {'agent-steps/s':>14}"
    )
    print(head)
    print("-" * len(head))
    for r in report["results"]:
        print(
            f"{r['api']:<12} {r['agents']:>7} {r['steps']:>6} {r['steps_per_s']:>9.1f} "
            f"{r['median_steps_per_s']:>8.1f} {r['agent_steps_per_s']:>14,.0f}"
        )
    print(f"(best of {report['repeat']} rounds; median beside it)")
    verdict = "met" if report["meets_target"] else "NOT met"
    print(f"target >= {report['target_steps_per_s']:.0f} steps/s through the array API: {verdict}")


# ------------------------------------------------------------------------------ tuning


def _tuning_kwargs(targets: int, frames: int, k: int) -> dict[str, Any]:
    return {
        "scenarios": {
            "scenarios": ["counterflow"],
            "agents": [targets, targets],
            "frames": frames,
            "warmup_steps": 25,
            "template_px": [12],
            "density_scale": [1.0, 1.0],
            "max_width": 1280,
            "max_height": 720,
        },
        "k_frames": k,
    }


def _run_episodes(env: Any, episodes: int) -> dict[str, float]:
    """Every episode of the pool once (reset, then steps with the default action until it
    ends): env steps, wall seconds in all and in ``step`` alone, mean targets."""
    action = np.zeros(env.action_space.shape, np.float32)
    steps, in_step, targets = 0, 0.0, []
    t0 = time.perf_counter()
    for i in range(episodes):
        env.reset(seed=i, options={"episode": i})
        done = False
        while not done:
            t1 = time.perf_counter()
            _, _, done, _, info = env.step(action)
            in_step += time.perf_counter() - t1
            steps += 1
            targets.append(info["targets"])
    wall = time.perf_counter() - t0
    return {
        "env_steps": steps,
        "wall_s": wall,
        "steps_per_s": steps / wall,
        "step_only_steps_per_s": steps / in_step,
        "mean_targets": float(np.mean(targets)),
    }


def _vector_rate(kwargs: dict[str, Any], workers: int, steps: int, seed: int) -> dict[str, Any]:
    """Env steps/s of ``workers`` asynchronous envs (``spawn``) over ``steps`` vector steps,
    episodes reset as they end (Gymnasium's next-step autoreset): a reset call is not counted
    as an env step, its time is."""
    from gymnasium.vector import AsyncVectorEnv

    from envs.tracker_tuning import TrackerTuningEnv

    vec = AsyncVectorEnv(
        [lambda: TrackerTuningEnv(**kwargs) for _ in range(workers)], context="spawn"
    )
    try:
        vec.reset(seed=[seed + i for i in range(workers)])
        actions = np.zeros((workers,) + vec.single_action_space.shape, np.float32)
        resetting = np.zeros(workers, bool)
        counted = 0
        t0 = time.perf_counter()
        for _ in range(steps):
            _, _, term, trunc, _ = vec.step(actions)
            counted += int((~resetting).sum())
            resetting = term | trunc
        wall = time.perf_counter() - t0
    finally:
        vec.close()
    return {"workers": workers, "env_steps": counted, "wall_s": wall, "steps_per_s": counted / wall}


def bench_tuning(
    targets: tuple[int, ...] = (100, 300),
    workers: tuple[int, ...] = (1, 2),
    episodes: int = 4,
    frames: int = 100,
    k: int = 25,
    vector_steps: int = 24,
    seed: int = 0,
    cache_dir: str | None = None,
    repeat: int = 1,
) -> dict[str, Any]:
    """TrackerTuning-v0 env steps/s with and without the episode cache, per crowd size, and
    the speed-up of asynchronous envs.

    Per size: a pool of ``episodes`` episodes of ``frames`` frames, filled into an
    :class:`envs.episodes.EpisodeCache` (timed apart), then ``repeat`` rounds, each running
    every episode once from reset to its end rendering it at its reset (no cache), then
    reading it back from the cache. The best round of each counts (the rounds alternate, so
    a slower spell of a shared machine falls on both). The rate counts resets;
    ``step_only`` leaves them out (the tracking alone). Then ``workers`` asynchronous envs
    on the first size, with and without the cache.
    """
    import os
    import tempfile
    from pathlib import Path

    from envs.tracker_tuning import TrackerTuningEnv

    with tempfile.TemporaryDirectory(prefix="crowdsim-bench-episodes-") as tmp:
        root = cache_dir or tmp
        sizes = []
        for n in targets:
            kw = dict(_tuning_kwargs(n, frames, k), pool=episodes)
            plain = TrackerTuningEnv(**kw)
            t0 = time.perf_counter()
            cached_env = TrackerTuningEnv(**kw, episode_cache=root)
            fill = cached_env.episodes.fill(progress=False)
            fill["wall_s"] = time.perf_counter() - t0
            rounds = [
                (_run_episodes(plain, episodes), _run_episodes(cached_env, episodes))
                for _ in range(repeat)
            ]
            rendered = max((r for r, _ in rounds), key=lambda r: r["steps_per_s"])
            cached = max((c for _, c in rounds), key=lambda c: c["steps_per_s"])
            sizes.append(
                {
                    "people": n,
                    "frames": frames,
                    "k": k,
                    "episodes": episodes,
                    "frame": f"{plain._ep.seq.width}x{plain._ep.seq.height}",
                    "rounds": repeat,
                    "rendered": rendered,
                    "cached": cached,
                    "fill": fill,
                    "speedup": cached["steps_per_s"] / rendered["steps_per_s"],
                }
            )
            plain.close()
            cached_env.close()
        kw = dict(_tuning_kwargs(targets[0], frames, k), pool=episodes)
        vec_rows = []
        for mode, extra in (("rendered", {}), ("cached", {"episode_cache": root})):
            for w in workers:
                row = _vector_rate(dict(kw, **extra), w, vector_steps, seed)
                row["mode"] = mode
                vec_rows.append(row)
        cache_bytes = sum(p.stat().st_size for p in Path(root).rglob("*") if p.is_file())
    for mode in ("rendered", "cached"):
        rows = [r for r in vec_rows if r["mode"] == mode]
        base = next((r["steps_per_s"] for r in rows if r["workers"] == 1), None)
        for r in rows:
            r["speedup"] = r["steps_per_s"] / base if base else None
    return {
        "env": "crowdsim/TrackerTuning-v0",
        "tracker": "bqp (paper defaults)",
        "cpus": os.cpu_count(),
        "sizes": sizes,
        "vector": vec_rows,
        "vector_people": targets[0],
        "vector_steps": vector_steps,
        "cache_bytes": cache_bytes,
    }


def _print_tuning(report: dict[str, Any]) -> None:
    print(f"TrackerTuning-v0 ({report['tracker']}), {report['cpus']} CPUs")
    head = (
        f"{'people':>7} {'targets':>8} {'frame':>9} {'K':>3} {'rendered':>9} {'cached':>8} "
        f"{'speed-up':>9} {'step only':>10} {'fill s/ep':>10}"
    )
    print(head)
    print("-" * len(head))
    for r in report["sizes"]:
        ren, cac = r["rendered"], r["cached"]
        print(
            f"{r['people']:>7} {cac['mean_targets']:>8.0f} {r['frame']:>9} {r['k']:>3} "
            f"{ren['steps_per_s']:>9.2f} {cac['steps_per_s']:>8.2f} {r['speedup']:>8.2f}x "
            f"{cac['step_only_steps_per_s']:>10.2f} {r['fill']['wall_s'] / r['episodes']:>10.2f}"
        )
    rounds = report["sizes"][0].get("rounds", 1) if report["sizes"] else 1
    print(
        "(env steps/s over whole episodes, resets included: each reset renders its episode, "
        "or reads it from the episode cache; 'step only' leaves resets out; best of "
        f"{rounds} rounds, rendered and cached in turn)"
    )
    print(f"async vector env, {report['vector_people']} people per env")
    head = f"{'episodes':>9} {'workers':>7} {'env steps':>10} {'steps/s':>8} {'speed-up':>9}"
    print(head)
    print("-" * len(head))
    for r in report["vector"]:
        sp = "" if r["speedup"] is None else f"{r['speedup']:.2f}x"
        print(
            f"{r['mode']:>9} {r['workers']:>7} {r['env_steps']:>10} {r['steps_per_s']:>8.2f} "
            f"{sp:>9}"
        )


# ------------------------------------------------------------------------------ CLI

SECTIONS: dict[
    str, tuple[Callable[[argparse.Namespace], dict[str, Any]], Callable[[dict[str, Any]], None]]
] = {
    "crowd": (lambda a: bench_crowd(a.agents, a.steps, a.warmup, a.seed, a.repeat), _print_crowd),
    "tuning": (
        lambda a: bench_tuning(
            tuple(a.targets),
            tuple(a.workers),
            a.episodes,
            a.frames,
            a.k,
            a.vector_steps,
            a.seed,
            a.episode_cache,
            a.repeat,
        ),
        _print_tuning,
    ),
}
"""Section name -> (run it from the parsed arguments, print its table)."""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--only",
        default=",".join(SECTIONS),
        help=f"comma-separated sections to run: {', '.join(SECTIONS)} (default: all)",
    )
    parser.add_argument(
        "--agents", type=int, default=1000, help="crowd: pedestrians, all agents (default 1000)"
    )
    parser.add_argument(
        "--steps", type=int, default=200, help="crowd: timed steps per API (default 200)"
    )
    parser.add_argument(
        "--warmup", type=int, default=20, help="crowd: untimed steps first (default 20)"
    )
    parser.add_argument(
        "--repeat",
        type=int,
        default=3,
        help="crowd and tuning: timing rounds, the best counts (default 3)",
    )
    parser.add_argument(
        "--targets",
        type=int,
        nargs="+",
        default=[100, 300],
        help="tuning: people per crowd (default 100 300)",
    )
    parser.add_argument(
        "--workers",
        type=int,
        nargs="+",
        default=[1, 2],
        help="tuning: async env counts, e.g. 1 2 4 8 16 (default 1 2)",
    )
    parser.add_argument(
        "--episodes",
        type=int,
        default=4,
        help="tuning: episodes in the pool, each run once per measurement (default 4)",
    )
    parser.add_argument(
        "--frames", type=int, default=100, help="tuning: frames per episode (default 100)"
    )
    parser.add_argument(
        "--vector-steps",
        type=int,
        default=24,
        help="tuning: vector steps per async measurement (default 24)",
    )
    parser.add_argument(
        "--episode-cache",
        default=None,
        metavar="DIR",
        help="tuning: keep the cached episodes in DIR (default: a temporary folder)",
    )
    parser.add_argument("--k", type=int, default=25, help="tuning: frames per env step (25)")
    parser.add_argument("--seed", type=int, default=0, help="seed of scenes and actions")
    parser.add_argument(
        "--json-out", default=None, metavar="FILE", help="also write the JSON to FILE"
    )
    parser.add_argument("--overwrite", action="store_true", help=OVERWRITE_HELP)


def _sections(text: str) -> list[str]:
    chosen = [s.strip() for s in text.split(",") if s.strip()]
    unknown = sorted(set(chosen) - set(SECTIONS))
    if unknown or not chosen:
        raise ValueError(
            f"--only: unknown or no section(s) {', '.join(unknown) or text!r}; "
            f"choose from {', '.join(SECTIONS)}"
        )
    return chosen


def run(args: argparse.Namespace) -> int:
    chosen = _sections(args.only)
    for name in ("agents", "steps", "repeat", "episodes", "vector_steps", "k"):
        if getattr(args, name, 1) < 1:
            flag = "--" + name.replace("_", "-")
            raise ValueError(f"{flag} must be >= 1, got {getattr(args, name)}")
    for name in ("targets", "workers"):
        bad = [v for v in getattr(args, name, None) or () if v < 1]
        if bad:
            raise ValueError(f"--{name} must be >= 1, got {bad[0]}")
    if getattr(args, "workers", None):
        from crowdsim.checks import require_cpus

        require_cpus("--workers", args.workers)  # each async env is a process
    if getattr(args, "episode_cache", None):
        from crowdsim.checks import require_output_dir

        require_output_dir("--episode-cache", args.episode_cache)
    if getattr(args, "frames", 2) < 2:
        raise ValueError(f"--frames must be >= 2, got {args.frames}")
    if getattr(args, "warmup", 0) < 0:
        raise ValueError(f"--warmup must be >= 0, got {args.warmup}")
    if args.json_out:  # before any run
        from crowdsim.atomic import require_replaceable

        require_replaceable("--json-out", args.json_out, args.overwrite)
    report: dict[str, Any] = {"benchmark": "envs", "sections": {}}
    for name in chosen:
        bench, show = SECTIONS[name]
        report["sections"][name] = result = bench(args)
        show(result)
        print()
    text = json.dumps(report)
    print(text)
    if args.json_out:
        from crowdsim.atomic import recorded, write_text_atomic

        with recorded(args.json_out):
            write_text_atomic(args.json_out, text + "\n")
    return 0
