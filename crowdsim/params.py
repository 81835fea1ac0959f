"""Parameters of the social-force model (SPEC §3), in SI units.

Every constant the simulator uses lives in :class:`SocialForceParams`; each field names its
symbol in Helbing & Molnár (1995) [HM95], Helbing, Farkas & Vicsek (2000) [HFV00] or
Moussaïd et al. (2010) [M10], with its unit.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields
from typing import Any

from crowdsim.checks import require_choice, require_number

POTENTIALS = ("elliptic", "exponential")
DEFAULT_DT: float = 0.04
"""The time step ``contact_substeps`` is set for, s (:attr:`SocialForceParams.substeps`)."""
MAX_PYMUNK_STEPS: int = 10_000
"""Largest ``contact_substeps`` and ``solver_iterations``: 1e20 sub-steps ran for ever, and
pymunk takes the iterations as a C int (3e9 raised ``OverflowError`` from its first step)."""


@dataclass(frozen=True)
class SocialForceParams:
    """Social-force model with group terms, integrated by pymunk.

    Per agent ``i`` (unit mass; forces are accelerations, m/s²)::

        dv_i/dt = (v0_i e_i - v_i)/tau + sum_j w(phi_ij) f_ij + sum_W f_iW + f_group_i

    Attributes
    ----------
    dt : float
        Integration time step, s. Default 0.04 s (25 frames/s).
    tau : float
        Relaxation time ``tau`` of the driving term [HM95 Eq. 2], s.
    headway_time : float
        Time headway ``T`` (s): the speed cap becomes ``min(1.3 v0, (v0 / v_ref) gap / T)``,
        where ``gap`` is the free distance along ``e_i`` to the nearest body in a cone ahead
        that heads the same way (desired directions within 60°). Plain HM95 forces keep a
        dense unidirectional crowd near free speed, far above Weidmann's fundamental diagram;
        this self-stopping rule (Parisi, Gilman & Moldovan 2009, Physica A 388; the headway law
        of Tordeux et al.'s collision-free speed model, 2016) restores it. 0 disables it (pure
        HM95).
    headway_ref_speed : float
        ``v_ref`` (m/s): a walker at this desired speed needs ``v_ref T`` of free gap to walk
        freely; everybody keeps the same gap relative to their own pace, so a pack of
        runners still runs (2.7 m/s at 1 /m² in ``marathon``) where walkers slow down.
    headway_cone_deg : float
        Half-angle of the cone ahead in which bodies limit the headway, degrees (< 60 keeps
        two agents from blocking each other).
    headway_depth : float
        Fraction of the touching distance counted along the walking direction in the
        headway: bodies are about 2/3 as deep front-to-back as they are wide, so people close
        up further behind each other than side by side.
    potential : str
        ``"elliptic"``: pedestrian potential ``V(b) = V0 exp(-b/sigma)`` over the semi-minor
        axis ``b`` of the ellipse spanned by the other's step ``v_j * delta_t`` [HM95 Eq. 4];
        ``"exponential"``: circular ``A exp((r_ij - d_ij)/B)`` [HFV00], the repulsion term
        alone: HFV00's body force and sliding friction (``k``, ``kappa``) are not modelled,
        pymunk's rigid contacts (friction 0.3) stand in for them.
    V0 : float
        Pedestrian potential strength ``V0_ab`` [HM95], m²/s².
    sigma : float
        Pedestrian potential range ``sigma`` [HM95], m.
    step_time : float
        ``delta_t`` of the elliptic potential (the other's step ``v_j delta_t``) [HM95], s.
    b_min : float
        Smallest semi-minor axis ``b`` used by the elliptic potential, m. ``grad b`` diverges
        as ``b -> 0`` (a body right on the other's step); bounding ``b`` bounds the force
        there, instead of kicking agents sideways into their neighbours.
    A : float
        Exponential repulsion strength ``A_i`` [HFV00] divided by the 80 kg mass, m/s².
    B : float
        Exponential repulsion range ``B_i`` [HFV00], m.
    U0 : float
        Wall potential strength ``U0_aB`` [HM95 Eq. 5], m²/s².
    R : float
        Wall potential range ``R`` [HM95], m.
    fov_deg : float
        Field of view ``2 phi`` [HM95 Eq. 8], degrees; forces from outside are weighted by ``c``.
    c : float
        Weight ``c`` of interactions outside the field of view [HM95 Eq. 8].
    speed_cap : float
        Maximal speed as a multiple of ``v0_i`` (``v_max = 1.3 v0`` [HM95 Eq. 10]).
    cutoff : float
        Interaction range for pedestrian and wall terms, m. Beyond it the pedestrian force is
        below ``V0/sigma exp(-cutoff/sigma)`` (1.5 m: 0.047 m/s², 3 % of the force at contact
        distance) and is neglected; it is also the side of the neighbour-grid cells. The
        fundamental diagram and lane order of ``crowdsim bench fd`` are the same with 2 m.
    beta1, beta2, beta3 : float
        Group vision, attraction and repulsion strengths [M10], m/s² (per radian for beta1
        scaled by speed).
    group_gaze_deg : float
        Half field of vision used by the group vision term [M10], degrees.
    group_repulsion_gap : float
        Gap added to the radii below which group members repel each other [M10], m.
    mass : float
        Body mass for pymunk contacts, kg (forces are scaled by it).
    friction : float
        Coulomb friction coefficient between bodies in contact (pymunk).
    contact_slop : float
        Allowed contact overlap before pymunk corrects it, m.
    contact_bias : float
        Fraction of a contact overlap left uncorrected after one second (pymunk's
        ``collision_bias``; its default 0.0018 leaves 22 % of an overlap after a 0.04 s step).
    contact_substeps : int
        pymunk steps per time step (forces held fixed). Bodies move before pymunk detects a
        contact, so one step can sink two walkers meeting head-on at 2.7 m/s 0.11 m deep;
        three sub-steps keep overlaps near 10 % of the radius (two: up to 19 %). That is
        at the default ``dt`` of 0.04 s: a longer ``dt`` takes this many for each started
        0.04 s (:attr:`substeps`). At most :data:`MAX_PYMUNK_STEPS`.
    solver_iterations : int
        pymunk contact solver iterations per step, at most :data:`MAX_PYMUNK_STEPS`.
    """

    dt: float = 0.04
    tau: float = 0.5
    headway_time: float = 0.49
    headway_ref_speed: float = 1.34
    headway_cone_deg: float = 35.0
    headway_depth: float = 0.95
    potential: str = "elliptic"
    V0: float = 2.1
    sigma: float = 0.3
    step_time: float = 0.4
    b_min: float = 0.1
    A: float = 25.0
    B: float = 0.08
    U0: float = 10.0
    R: float = 0.2
    fov_deg: float = 200.0
    c: float = 0.6
    speed_cap: float = 1.3
    cutoff: float = 1.5
    beta1: float = 4.0
    beta2: float = 3.0
    beta3: float = 1.0
    group_gaze_deg: float = 90.0
    group_repulsion_gap: float = 0.3
    mass: float = 80.0
    friction: float = 0.3
    contact_slop: float = 0.005
    contact_bias: float = 1e-6
    contact_substeps: int = 3
    solver_iterations: int = 10

    def __post_init__(self) -> None:
        own = "SocialForceParams"
        require_choice(own, "potential", self.potential, POTENTIALS)
        positive = (
            "dt",
            "tau",
            "sigma",
            "step_time",
            "b_min",
            "B",
            "R",
            "speed_cap",
            "cutoff",
            "mass",
            "contact_slop",
            "headway_ref_speed",
        )
        nonneg = (
            "headway_time",
            "V0",
            "A",
            "U0",
            "beta1",
            "beta2",
            "beta3",
            "friction",
            "group_repulsion_gap",
            "group_gaze_deg",
        )
        for name in positive:
            require_number(own, name, getattr(self, name), lo=0, lo_open=True)
        for name in nonneg:
            require_number(own, name, getattr(self, name), lo=0)
        for name in ("solver_iterations", "contact_substeps"):
            require_number(own, name, getattr(self, name), lo=1, hi=MAX_PYMUNK_STEPS, integer=True)
        require_number(own, "dt", self.dt, lo=0, hi=0.2, lo_open=True)  # stable integration
        require_number(own, "fov_deg", self.fov_deg, lo=0, hi=360, lo_open=True)
        require_number(own, "headway_depth", self.headway_depth, lo=0, hi=1, lo_open=True)
        require_number(
            own, "headway_cone_deg", self.headway_cone_deg, lo=0, hi=60, lo_open=True, hi_open=True
        )
        require_number(
            own, "contact_bias", self.contact_bias, lo=0, hi=1, lo_open=True, hi_open=True
        )
        require_number(own, "c", self.c, lo=0, hi=1)
        require_number(own, "speed_cap", self.speed_cap, lo=1)  # a multiple of v0

    @property
    def substeps(self) -> int:
        """pymunk sub-steps per time step: ``contact_substeps`` for each started 0.04 s
        (:data:`DEFAULT_DT`) of ``dt`` (at ``dt`` 0.2 s and three sub-steps, walkers sank up
        to 0.88 of their radius into each other, and bodies driven at 10 m/s went through a
        wall)."""
        return int(self.contact_substeps) * max(1, math.ceil(self.dt / DEFAULT_DT - 1e-9))

    def replace(self, **changes: Any) -> SocialForceParams:
        """A copy with some fields changed (validated like the constructor)."""
        unknown = set(changes) - {f.name for f in fields(self)}
        if unknown:
            raise ValueError(f"unknown social-force parameter(s): {', '.join(sorted(unknown))}")
        return SocialForceParams(**{**asdict(self), **changes})

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)
