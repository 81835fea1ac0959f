"""Parameters of the BQP tracker (paper 1, ``papers/bqp-frank-wolfe-tracker.txt``).

One frozen dataclass holds every weight, threshold and size the tracker uses, named after the
paper's symbols. Lengths are given in units of the template (target) size ``s`` so that one
parameter set works for sequences with 8 px and 16 px heads; the tracker converts them to
pixels once the template size is known.
"""

from __future__ import annotations

from dataclasses import dataclass, fields

from crowdsim.checks import require_choice, require_number
from tracker.bqp.frank_wolfe import VARIANTS as FW_VARIANTS
from tracker.cmc import check_fields as check_cmc_fields

APPEARANCE_MODELS: tuple[str, ...] = ("kcf", "ncc")
NEIGHBOUR_SETS: tuple[str, ...] = ("nearest", "group")
"""``BQPParams.neighbour_set``: today's ``N_i`` and Eq. 7's."""
IDENTITIES: tuple[str, ...] = ("linked", "every")
"""``BQPParams.laplacian_identity``: today's diagonal and the paper's identity."""


UPPER: dict[str, float] = {
    "search_factor": 8.0,
    "history": 1000,
    "n_neighbours": 50,
    "n_extrema": 50,
    "n_samples": 500,
    "sample_window": 100,
    "candidate_stride": 64,
    "fw_max_iter": 10_000,
    "group_radius": 20.0,
    "neighbour_scale": 20.0,
    "motion_sigma": 20.0,
    "proximity_sigma": 10.0,
    "proximity_cutoff": 10.0,
    "group_sigma": 10.0,
    "group_cutoff": 10.0,
    "kcf_target_window": 8.0,
}
"""Upper bounds of the fields whose size is memory or time: the search grid grows with the
square of ``search_factor``, the candidates with ``n_extrema * n_samples``, the quadratic terms'
pairs with the square of the radii and cut-offs (templates), the solver's work with
``fw_max_iter``. A value beyond them can only exhaust the machine, so it is refused by name
instead of ending in "out of memory"."""


@dataclass(frozen=True, kw_only=True)
class BQPParams:
    """Every tunable constant of the BQP tracker.

    Objective (Eq. 1): ``c_a.x + zeta c_m.x + eta c_nm.x + w_sp x^T C_sp x + w_g x^T C_g x``.

    Attributes
    ----------
    zeta : float
        Weight of the target-motion term ``c_m`` (Eq. 1, Eq. 6). Paper: 0.3.
    eta : float
        Weight of the neighbourhood-motion term ``c_nm`` (Eq. 1, Eq. 7-8). Paper: 0.2.
    w_sp : float
        Weight of the spatial-proximity quadratic term ``C_sp`` (Eq. 1, Eq. 9). The paper has
        no weight (1); with our signless Laplacian and sparse candidates 1 pushes neighbours
        in dense crowds apart too hard (speed-up sampling lost ~1.5 points at 15 px on a
        150-person synthetic crowd), 0.3 loses nothing.
    w_g : float
        Weight of the grouping quadratic term ``C_g`` (Eq. 1, Eq. 10). Paper: 1.
    update_threshold : float
        The appearance model of a target is updated only when the appearance confidence of its
        selected candidate is at least this value (Sec. 7.1). Paper: 0.6.
    appearance : str
        ``"kcf"``: multi-channel colour correlation filter, Eq. 4-5; ``"ncc"``: NCC template.
    search_factor : float
        Side of the search region in template sizes (Sec. 7: twice the target size). Candidate
        centres lie within ``r = round((search_factor - 1) s / 2)`` px of the search centre.
    kcf_lambda : float
        Ridge regulariser ``lambda`` of Eq. 4.
    kcf_learning_rate : float
        Interpolation factor of the KCF model update, updated as in [15] (whose code takes
        0.075 for raw pixels and 0.02 for HOG features; 0.05 here, not measured against
        either).
    kcf_label_sigma : float
        Standard deviation of the Gaussian regression target ``y`` of Eq. 4, template sizes.
    kcf_kernel : str
        ``"gaussian"`` (KCF's Gaussian kernel, [15]) or ``"linear"`` (plain ridge regression
        of Eq. 4 on the colour channels).
    kcf_target_window : float
        Side (template sizes) of the Hann window applied to *training* patches, zero outside;
        0 = KCF's window over the whole search region. Detection always uses the whole
        region. Default 1.6: with the whole region the filter also learns the static ground
        around a walking person and lags behind; on a low-contrast synthetic crowd this
        raised BQP's accuracy at 5 px from 95.0 to 96.3 %.
    kcf_kernel_sigma : float
        Bandwidth of the Gaussian kernel (features are pixel values / 255, mean-removed).
    ncc_update_every : int
        NCC templates are refreshed every this many frames (Sec. 7.1: 10).
    motion_sigma : float
        ``Sigma = motion_sigma^2 I`` of the Gaussian of Eq. 6 and Eq. 7, template sizes.
    velocity_smoothing : float
        Exponential smoothing of the velocity ``p_dot`` in the state ``s = [p, p_dot]`` of
        Eq. 6 (0 = last displacement only).
    n_neighbours : int
        Maximum size of the neighbour set ``N_i`` of Eq. 7 (paper: 5).
    neighbour_set : str
        Which targets ``N_i`` holds (:func:`tracker.bqp.terms.neighbours_in_groups`):
        ``"nearest"`` (default, every figure of the README), the same-group targets among the
        ``n_neighbours`` nearest of any group, so where two groups interleave (counterflow
        lanes) a target is left with fewer or none; ``"group"``, Eq. 7's: the
        ``n_neighbours`` nearest targets of its own group. Both within ``group_radius``.
    neighbour_scale : float
        Length unit of the distance in the weights of Eq. 8, template sizes (the paper leaves
        the unit implicit; in pixels the weights would collapse onto the nearest neighbour).
    history : int
        Frames of track history used to find coherent-motion groups (paper: t-10 .. t-1).
    group_refresh : int
        Groups and their spanning trees are refreshed every ``tau`` frames (paper: 10).
    coherence_threshold : float
        Minimum mean cosine similarity of two targets' velocities over ``history`` frames for
        them to move coherently.
    group_radius : float
        Maximum distance between coherent neighbours, template sizes.
    min_group_speed : float
        Targets slower than this (px/frame, mean over the history) join no coherent group:
        the direction of a standing person's jitter carries no motion information.
    proximity_sigma : float
        ``sigma`` of Eq. 9, template sizes (paper: half the target size).
    proximity_cutoff : float
        Entries of ``S`` (Eq. 9) beyond ``proximity_cutoff * sigma`` are dropped (sparse
        ``S``; entries below ``exp(-1.125) = 0.32``). 1.5 instead of 2 made 1000 targets at
        2.5 people/m^2 18 % faster for accuracy changes within +-0.2 points.
    group_sigma : float
        ``sigma`` of Eq. 10, template sizes (the paper reuses Eq. 9's, half the target size;
        0.25 here, and the deviation ``|p_i - p_j| - e_ij`` is squared, as SPEC has it: the
        paper prints it unsquared).
    laplacian_tau : float
        Degree regulariser ``tau`` of both normalised Laplacians,
        ``(D + tau I)^-1/2 (D -/+ W) (D + tau I)^-1/2`` (0 = the paper's ``I -/+ D^-1/2 W
        D^-1/2``); see :func:`tracker.bqp.quadratic.quadratic_matrix`. Default 1: with ``tau = 0``
        a candidate pair that is barely similar but has no other neighbour gets a
        full-strength proximity penalty, which cost 0.4 points at 5 px on a 300-person
        synthetic crowd; ``tau = 1`` lost nothing.
    laplacian_identity : str
        Where the Laplacians' identity sits. ``"linked"`` (default, every figure of the
        README): ``D / (D + tau)`` on the diagonal, so only on candidates with a neighbour,
        and on binary points the terms are no constant: two targets on one grouping edge pay
        0 for keeping their formation, 0.5 (tau 1) for breaking it on one side and 0 for
        breaking it on both. ``"every"``, the paper's ``I`` on every candidate: a constant on
        binary points, where the terms reduce to their off-diagonal entries (keeping 0,
        breaking on one side or both 2 with tau 0). It is reached by taking ``Q``'s diagonal
        off the linear cost, which gives the paper's objective on every binary point and keeps
        the relaxation's curvature (the paper's ``I`` in the relaxation would add ``|x|^2``
        on every simplex, pulling the relaxed optimum further inside them). Measured on the
        full ``ucf9`` with ``neighbour_set="group"`` too (the README's "paper's forms,
        measured"): mean acc@15 92.0 against 92.9 % (KCF), 86.1 against 87.6 (NCC); in
        Table 3 the grouping term no longer costs (-0.15 / -0.31 points against -1.6 /
        -1.6) and the proximity term does (-1.1 / -0.5 against +0.6 / +0.2).
    group_offsets : bool
        Grouping term on relative positions ``e_ij = p_i - p_j`` (2-vectors) instead of the
        distances ``|p_i - p_j|`` of Eq. 10; see :func:`tracker.bqp.quadratic.grouping_matrix`.
    group_cutoff : float
        Entries of ``Gamma`` (Eq. 10) with ``| |p_i - p_j| - e_ij | > group_cutoff * sigma`` are
        dropped (same reasoning as ``proximity_cutoff``).
    candidate_stride : int
        Pixel stride of the dense candidate grid (1 = every pixel of the search region).
    speedup : bool
        Speed-up sampling (Sec. 6) instead of dense candidates. Default on: it kept the
        accuracy on every sequence we measured (``crowdsim bench track``) and dense candidates
        (``(s+1)^2`` per target) make the quadratic terms of dense crowds 10-50x slower.
    n_extrema : int
        ``m``: extrema of the linear-term map kept per target (Sec. 6: 3).
    n_samples : int
        Extra candidates sampled around each extremum (Sec. 6: 10).
    sample_window : int
        Side of the square neighbourhood the extra samples are drawn from, px. The paper
        uses 6; with our 12 px templates in crowds of 2.5 people/m^2, 6 lost 1.2 points at
        5 px against dense candidates and 10 lost 0.2 (``crowdsim bench track``), so 10.
    distinct_samples : bool
        ``False`` (default, kept so no figure moves): a sample clipped onto the grid's edge,
        or drawn on another extremum or another's sample, repeats a candidate of its target
        (4-7 of 33 on 9 x 9 to 13 x 13 grids), and a repeat counts again in the degrees of
        Eq. 9-10's Laplacians. ``True``: no location is a target's candidate twice, as the
        paper's candidates are locations, where the search grid has at least ``k`` cells
        (:func:`tracker.candidates.speedup_candidates`; a smaller grid keeps the repeats).
    fw_variant : str
        Frank-Wolfe variant: ``"plain"``, ``"away"`` or ``"swap"`` (Sec. 5), or ``"block"``:
        SWAP steps on the chosen target until its gap closes, in closed form
        (:mod:`tracker.bqp.frank_wolfe`), the same objective and stopping test in a tenth of
        the steps on packed crowds; the paper's ``"swap"`` stays the default.
    fw_eps : float
        Duality-gap stop of Frank-Wolfe (paper: 0.01).
    fw_max_iter : int
        Iteration cap of the solver per target (the solver's iterations are block steps).
    border_penalty : float
        Cost added to candidates whose centre lies outside the image.
    seed : int
        Seed of the random generator of the speed-up sampling.
    lost_ratio : float
        A target whose appearance confidence stays below this fraction of its own usual
        confidence (a running mean, :attr:`tracker.base.Tracker.conf_ref`) for ``max_lost``
        frames in a row has lost its evidence and its track ends (people also vanish inside
        the view). Measured: on the uncalibrated ucf9 seq8 (people leave through doors in
        view) 0.4 / 5 frames raised BQP's MOTA from 96.4 to 98.1 % and IDF1 from 98.2 to
        99.1 % with acc@15 unchanged; on the calibrated seq6 and seq9 it costs 0.6 points of
        acc@15, where an absolute floor of 0.3 ended most correct tracks (46.4 -> 9.3 %).
    max_lost : int
        Frames in a row below ``lost_ratio`` times the usual confidence that end a track;
        0 = tracks end only when they leave the image.
    cmc : bool
        Camera-motion compensation (:mod:`tracker.cmc`; neither paper has one): before each
        frame's search, the global motion since the previous frame, estimated from the frames
        alone, moves the points, the velocities ``p_dot`` (so the search windows and the motion
        terms) and the groups' spanning-tree offsets (:attr:`BQPTracker.camera_state
        <tracker.bqp.tracker.BQPTracker.camera_state>`). Off: the papers' static camera.
    cmc_method : str
        How that motion is estimated: ``"sparse"`` (BoT-SORT's sparse optical flow with a
        RANSAC similarity) or ``"ecc"`` (:data:`tracker.cmc.METHODS`).
    """

    zeta: float = 0.3
    eta: float = 0.2
    w_sp: float = 0.3
    w_g: float = 1.0
    update_threshold: float = 0.6
    appearance: str = "kcf"
    search_factor: float = 2.0
    kcf_lambda: float = 1e-4
    kcf_learning_rate: float = 0.05
    kcf_label_sigma: float = 0.1
    kcf_kernel: str = "linear"
    kcf_kernel_sigma: float = 0.2
    kcf_target_window: float = 1.6
    ncc_update_every: int = 10
    motion_sigma: float = 0.5
    velocity_smoothing: float = 0.5
    n_neighbours: int = 5
    neighbour_set: str = "nearest"
    neighbour_scale: float = 1.0
    history: int = 10
    group_refresh: int = 10
    coherence_threshold: float = 0.8
    group_radius: float = 2.5
    min_group_speed: float = 0.3
    proximity_sigma: float = 0.5
    proximity_cutoff: float = 1.5
    group_sigma: float = 0.25
    group_cutoff: float = 1.5
    group_offsets: bool = False
    laplacian_tau: float = 1.0
    laplacian_identity: str = "linked"
    candidate_stride: int = 1
    speedup: bool = True
    n_extrema: int = 3
    n_samples: int = 10
    sample_window: int = 10
    distinct_samples: bool = False
    fw_variant: str = "swap"
    fw_eps: float = 0.01
    fw_max_iter: int = 50
    border_penalty: float = 10.0
    seed: int = 0
    lost_ratio: float = 0.4
    max_lost: int = 5
    cmc: bool = False
    cmc_method: str = "sparse"

    def __post_init__(self) -> None:
        own = "BQPParams"
        nonneg = (
            "zeta",
            "eta",
            "w_sp",
            "w_g",
            "min_group_speed",
            "border_penalty",
            "laplacian_tau",
            "kcf_target_window",
        )
        positive = (
            "kcf_lambda",
            "kcf_label_sigma",
            "kcf_kernel_sigma",
            "motion_sigma",
            "neighbour_scale",
            "group_radius",
            "proximity_sigma",
            "proximity_cutoff",
            "group_sigma",
            "group_cutoff",
            "fw_eps",
        )
        counts = (
            "ncc_update_every",
            "n_neighbours",
            "group_refresh",
            "candidate_stride",
            "n_extrema",
            "n_samples",
            "sample_window",
            "fw_max_iter",
        )
        for name in nonneg:
            require_number(own, name, getattr(self, name), lo=0, hi=UPPER.get(name))
        for name in positive:
            require_number(own, name, getattr(self, name), lo=0, lo_open=True, hi=UPPER.get(name))
        for name in counts:
            require_number(own, name, getattr(self, name), lo=1, integer=True, hi=UPPER.get(name))
        require_number(own, "history", self.history, lo=2, hi=UPPER["history"], integer=True)
        require_number(own, "seed", self.seed, lo=0, hi=2**63, hi_open=True, integer=True)
        require_number(own, "max_lost", self.max_lost, lo=0, integer=True)
        require_number(own, "lost_ratio", self.lost_ratio, lo=0, hi=1)
        require_number(own, "update_threshold", self.update_threshold, lo=0, hi=1)
        require_number(own, "kcf_learning_rate", self.kcf_learning_rate, lo=0, hi=1, lo_open=True)
        require_number(own, "velocity_smoothing", self.velocity_smoothing, lo=0, hi=1, hi_open=True)
        require_number(own, "coherence_threshold", self.coherence_threshold, lo=-1, hi=1)
        require_number(
            own, "search_factor", self.search_factor, lo=1, lo_open=True, hi=UPPER["search_factor"]
        )
        require_choice(own, "appearance", self.appearance, APPEARANCE_MODELS)
        require_choice(own, "kcf_kernel", self.kcf_kernel, ("gaussian", "linear"))
        require_choice(own, "fw_variant", self.fw_variant, FW_VARIANTS)
        require_choice(own, "neighbour_set", self.neighbour_set, NEIGHBOUR_SETS)
        require_choice(own, "laplacian_identity", self.laplacian_identity, IDENTITIES)
        require_choice(own, "distinct_samples", self.distinct_samples, (True, False))
        check_cmc_fields(own, self)

    @classmethod
    def field_names(cls) -> tuple[str, ...]:
        """Names of all parameters, in declaration order."""
        return tuple(f.name for f in fields(cls))
