"""A spec, simulated and seen through its camera: frames and ground truth without touching disk.

``spec -> simulate(spec) -> camera_for(...) -> Scene -> frames / gt pixels``. Both the
writer (:func:`synth_data.generate.build_sequence`, which renders to disk) and the in-memory
sequence (:meth:`synth_data.sequence.InMemorySequence.from_spec`) start from
:meth:`Scene.from_spec`, so a frame rendered in memory is the frame ``generate`` encodes as
JPEG (a test checks it on a tiny spec).
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass, replace
from functools import cached_property
from typing import Any

import numpy as np

from crowdsim.events import CROWD_EVENTS, Event, of_kind
from synth_data.spec import SequenceSpec

EXTENT_PERCENTILE = 1.0
"""The camera frames the 1st to 99th percentile of the crowd's positions on each axis."""
SETTLE_S = 3.0
"""Seconds after entering and before leaving during which positions do not set the frame."""
BYTES_PER_AGENT_STEP = 80
"""Working set of a spec per (simulated step, person): the recorder's rows (24 B), the dense
trajectories (16 B), the kept frames' copy (16 B), the camera's pixel tracks (16 B) and the
drawn visibility (8 B)."""


def simulate(spec: SequenceSpec) -> Any:
    """Run the spec's scenario: a :class:`~crowdsim.trajectories.Trajectories` of ``frames``
    rows after ``warmup_steps`` dropped steps (agents never present in them are dropped)."""
    from crowdsim.params import SocialForceParams
    from crowdsim.scenarios import make_scenario
    from crowdsim.simulation import Simulation
    from crowdsim.trajectories import Trajectories

    params = {k: v for k, v in spec.scenario.items() if k != "name"}
    scenario = make_scenario(spec.scenario["name"], **params)
    sf = SocialForceParams()
    if abs(sf.dt - 1.0 / spec.fps) > 1e-12:
        sf = replace(sf, dt=1.0 / spec.fps)
    sim = Simulation(scenario, seed=spec.seed, params=sf)
    # A scenario times its stoppers (anomalies' ``stop``) from the simulation's start; the
    # spec's clock starts at frame 0, after the warm-up (a 10 s warm-up had ended every stop
    # before the first frame, and people labelled stop never stood still in the video).
    sim.state.stop_start += spec.warmup_steps * sf.dt
    sim.state.stop_end += spec.warmup_steps * sf.dt
    check_memory(spec, sim)
    crowd = of_kind(spec.events, CROWD_EVENTS)
    if crowd:
        traj = _run_with_events(sim, spec, crowd)
    else:
        traj = sim.run(spec.warmup_steps + spec.frames - 1)
    pos = traj.positions[spec.warmup_steps :]
    keep = ~np.isnan(pos[..., 0]).all(axis=0)
    meta = dict(traj.meta)
    meta["warmup_steps"] = spec.warmup_steps
    return Trajectories(
        positions=pos[:, keep],
        ids=traj.ids[keep],
        dt=traj.dt,
        attributes={k: v[keep] for k, v in traj.attributes.items()},
        meta=meta,
    )


def check_memory(spec: SequenceSpec, sim: Any) -> None:
    """Refuse, before the first step, a spec whose trajectories cannot fit in memory: they
    are dense, one column per person ever present (a spec of 1,000,000 frames and 2,000
    people was simulated for hours, its memory growing, before any check). People the
    scenario's inflow brings count, at the strongest surge's rate. So does the rendering that
    follows (:func:`crowdsim.render.render_bytes`), at the spec's frame size or the largest
    it allows."""
    from crowdsim.checks import require_memory
    from crowdsim.render import render_bytes
    from crowdsim.world import expected_arrivals

    steps = spec.warmup_steps + spec.frames
    seconds = steps * sim.params.dt
    factor = np.ones(spec.frames)  # the surges' product on each frame
    for e in spec.events:
        if e.kind == "surge":
            factor[e.mask(spec.frames)] *= e.magnitude
    surge = float(factor.max())
    arrivals = surge * expected_arrivals(sim.sources, seconds)
    people = len(sim.state.ids) + arrivals
    inflow = f", about {arrivals:,.0f} more from the inflow" if arrivals > 0 else ""
    # the rendering that follows holds the kept frames and their per-person arrays; the
    # frame is fitted to the crowd later, so its largest allowed size counts here
    cam = spec.camera
    width, height = (cam["width"], cam["height"]) if "width" in cam else _max_size(cam)
    require_memory(
        f"{spec.source or spec.name}: frames = {spec.frames} (+ warmup_steps = "
        f"{spec.warmup_steps}) with scenario.n_agents = {spec.scenario.get('n_agents')}"
        f"{inflow} ({people:,.0f} people), simulated and rendered at up to {width}x{height} px",
        max(
            float(BYTES_PER_AGENT_STEP) * steps * people,
            float(render_bytes(width, height, spec.frames, math.ceil(people))),
        ),
    )


def _run_with_events(sim: Any, spec: SequenceSpec, events: tuple[Event, ...]) -> Any:
    """Step ``sim`` through the spec's frames with its crowd events (stop, surge).

    Frame ``f`` is the state after ``warmup_steps + f`` steps; an event acting on frame ``f``
    changes the step that produces it. ``stop`` holds the desired velocity of a seeded
    fraction of the people present at zero (people who arrive meanwhile stop too, with the
    same probability); ``surge`` multiplies every inflow's arrival rate.
    """
    if any(e.kind == "surge" for e in events) and not sim.sources:
        raise ValueError(
            f"{spec.name}: events: surge needs a scenario with inflow; "
            f"{spec.scenario['name']} has none"
        )
    rng = np.random.default_rng(np.random.SeedSequence([spec.seed, 0x5709]))
    base_sources = list(sim.sources)
    none = np.zeros(0, np.int64)
    # per stop event: the ids already drawn (sorted) and whether each stops
    drawn = {i: (none, np.zeros(0, bool)) for i, e in enumerate(events) if e.kind == "stop"}
    stopped = none
    for step in range(spec.warmup_steps + spec.frames - 1):
        f = step + 1 - spec.warmup_steps  # the frame this step produces
        factor = float(np.prod([e.magnitude for e in events if e.kind == "surge" and e.active(f)]))
        sim.sources = (
            [replace(src, rate=src.rate * factor) for src in base_sources]
            if factor != 1.0
            else base_sources
        )
        present = np.sort(sim.state.ids)
        hold = none
        for i, (ids, stops) in drawn.items():
            if not events[i].active(f):
                continue
            new = present[~np.isin(present, ids)]
            if len(new):  # each person draws once per event, in id order
                ids = np.concatenate([ids, new])
                stops = np.concatenate([stops, rng.random(len(new)) < events[i].magnitude])
                order = np.argsort(ids, kind="stable")
                drawn[i] = ids, stops = ids[order], stops[order]
            hold = np.union1d(hold, ids[stops])
        hold = np.intersect1d(hold, present)
        release = np.intersect1d(np.setdiff1d(stopped, hold), present)
        if len(release):
            sim.clear_desired(release)
        if len(hold):
            sim.set_desired(hold, np.zeros(2))
        stopped = hold
        sim.step()
    sim.sources = base_sources
    return sim.trajectories


def crowd_extent(
    traj: Any, percent: float = EXTENT_PERCENTILE, settle_s: float = SETTLE_S
) -> tuple[float, ...]:
    """``(xmin, ymin, xmax, ymax)`` metres holding all but ``percent`` % of the positions
    on each side: where the crowd is, not every straggler (the camera frames this).

    Positions within ``settle_s`` seconds (at most a quarter of the clip) of an agent
    entering (after the first frame) or leaving (before the last frame) do not count, so
    that sources and sinks, where people appear and vanish, fall outside the frame: in the
    video people walk in and out across its border, as they do in real footage.
    """
    present = traj.present
    t = present.shape[0]
    k = min(max(0, int(round(settle_s / traj.dt))), t // 4)  # short clips: a quarter
    settled = present.copy()
    if k:
        rows = np.arange(t)[:, None]
        seen = present.any(axis=0)
        first = np.where(seen, present.argmax(axis=0), 0)
        last = np.where(seen, t - 1 - present[::-1].argmax(axis=0), t - 1)
        settled &= ~((first > 0) & (rows < first + k))
        settled &= ~((last < t - 1) & (rows > last - k))
        if not settled.any():
            settled = present
    xy = traj.positions[settled]
    if len(xy) == 0:
        raise ValueError("the simulation produced no agent inside the recorded frames")
    if len(xy) > 2_000_000:  # a subsample is plenty for percentiles
        xy = xy[:: len(xy) // 1_000_000]
    lo = np.percentile(xy, percent, axis=0)
    hi = np.percentile(xy, 100.0 - percent, axis=0)
    return float(lo[0]), float(lo[1]), float(hi[0]), float(hi[1])


def _max_size(cam: dict[str, Any]) -> tuple[int, int]:
    """The largest frame a spec's ``[camera]`` table lets the camera fit to the crowd, px."""
    from crowdsim.camera import FIT_MAX_SIZE

    return int(cam.get("max_width", FIT_MAX_SIZE[0])), int(cam.get("max_height", FIT_MAX_SIZE[1]))


def camera_for(
    spec_camera: dict[str, Any],
    template_px: int,
    extent: tuple[float, ...],
    seed: int,
    focus: tuple[float, float] | None = None,
    events: tuple[Event, ...] = (),
) -> Any:
    """The :class:`~crowdsim.camera.Camera` of a spec's ``[camera]`` table for ``extent``.

    Without an explicit ``center`` the camera looks at the centre of ``extent``; when the
    frame is smaller than the extent it moves towards ``focus`` (e.g. the crowd's median
    position) as far as it can while staying inside the extent. The shake ``events`` become
    the camera's shake bursts.
    """
    from crowdsim.camera import Camera, motion_values
    from crowdsim.render import default_px_per_m

    cam = spec_camera
    if ("width" in cam) != ("height" in cam):
        raise ValueError("camera: give both width and height, or neither")
    size = (cam["width"], cam["height"]) if "width" in cam else None
    camera = Camera.fit(
        extent,
        px_per_m=float(cam.get("px_per_m", default_px_per_m(template_px))),
        size=size,
        margin_m=float(cam.get("margin_m", 1.0)),
        max_size=_max_size(cam),
        tilt_deg=float(cam.get("tilt_deg", 0.0)),
        distance_m=float(cam.get("distance_m", 60.0)),
        **motion_values(cam),
        seed=seed,
        shake_events=of_kind(events, ("shake",)),
        ground_margin_px=cam.get("ground_margin_px", 0),
    )
    if "center" in cam:
        camera = replace(camera, center=tuple(float(c) for c in cam["center"]))
    elif focus is not None:
        half = (camera.width / camera.px_per_m / 2.0, camera.height / camera.px_per_m / 2.0)
        centre = []
        for axis in (0, 1):
            lo, hi = extent[axis], extent[axis + 2]
            if hi - lo <= 2 * half[axis]:
                centre.append((lo + hi) / 2.0)
            else:
                centre.append(float(np.clip(focus[axis], lo + half[axis], hi - half[axis])))
        camera = replace(camera, center=(centre[0], centre[1]))
    return camera


@dataclass(frozen=True)
class Scene:
    """Trajectories seen through a camera with an appearance: draws frames on demand.

    Attributes
    ----------
    name : str
    traj : crowdsim.trajectories.Trajectories
        One row per frame; ``traj.dt`` sets the frame rate.
    camera : crowdsim.camera.Camera
    appearance : crowdsim.appearance_model.AppearanceParams
    seed : int
        Seed of the rendering randomness (as in :func:`synth_data.writer.write_sequence`).
    events : tuple of crowdsim.events.Event
        The spec's events; the renderer draws the lighting and noise ones (the shake bursts
        are in the camera, the crowd events in the trajectories).
    """

    name: str
    traj: Any
    camera: Any
    appearance: Any
    seed: int
    events: tuple[Event, ...] = ()

    @classmethod
    def from_spec(cls, spec: SequenceSpec) -> Scene:
        """Simulate ``spec`` and frame the crowd as ``crowdsim generate`` does."""
        traj = simulate(spec)
        xy = traj.positions[traj.present]
        focus = (float(np.median(xy[:, 0])), float(np.median(xy[:, 1])))
        camera = camera_for(
            spec.camera,
            spec.appearance.template_px,
            crowd_extent(traj),
            spec.seed,
            focus=focus,
            events=spec.events,
        )
        return cls(
            name=spec.name,
            traj=traj,
            camera=camera,
            appearance=spec.appearance,
            seed=spec.seed,
            events=spec.events,
        )

    @property
    def frame_rate(self) -> float:
        return float(self.traj.fps)

    @property
    def length(self) -> int:
        return int(self.traj.positions.shape[0])

    @property
    def width(self) -> int:
        return int(self.camera.width)

    @property
    def height(self) -> int:
        return int(self.camera.height)

    @property
    def template_size(self) -> int:
        return int(self.appearance.template_px)

    @cached_property
    def tracks(self) -> Any:
        """The renderer's :class:`~crowdsim.render.AgentTracks` (pixels, headings, looks)."""
        from crowdsim.render import prepare_agents

        return prepare_agents(self.traj, self.camera, self.appearance, self.seed)

    @cached_property
    def renderer(self) -> Any:
        """The :class:`~crowdsim.render.SceneRenderer` (stateless per frame index)."""
        from crowdsim.render import SceneRenderer

        return SceneRenderer(
            self.camera, self.appearance, seed=self.seed, fps=self.traj.fps, events=self.events
        )

    def frame(self, t: int) -> np.ndarray:
        """Frame ``t`` (0-based) as a new ``(H, W, 3)`` uint8 BGR array."""
        if not (0 <= t < self.length):
            raise ValueError(f"{self.name}: frame index must be in [0, {self.length - 1}], got {t}")
        return self.renderer.render_tracks(self.tracks, t)

    def frames(self) -> Iterator[np.ndarray]:
        """Every frame in order, each a new ``(H, W, 3)`` uint8 BGR array."""
        for t in range(self.length):
            yield self.frame(t)

    def gt_points(self) -> tuple[np.ndarray, np.ndarray]:
        """``(ids (N,) int64, points (T, N, 2) float64)``: MOT ids (as written to ``gt.txt``)
        of the agents seen at least once, head centres in pixels, NaN where absent or outside
        the frame (the rows :func:`synth_data.mot.gt_rows` would write)."""
        from synth_data.mot import mot_ids

        pix = self.tracks.pixels
        vis = self.camera.visible(pix)
        seen = vis.any(axis=0)
        ids = mot_ids(self.tracks.ids)[seen]
        order = np.argsort(ids, kind="stable")  # ascending, as the MOT reader gives them
        points = np.where(vis[..., None], pix, np.nan)[:, seen][:, order]
        return ids[order], points
