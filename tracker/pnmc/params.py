"""Parameters of the PNMC tracker (paper 2: prominence + neighbourhood motion concurrence).

Lengths given "in template sizes" are multiplied by the sequence's template size ``s`` (px),
so one parameter set serves the 8-16 px templates of the benchmark sequences.
"""

from __future__ import annotations

from dataclasses import dataclass

from crowdsim.checks import require_choice, require_number
from tracker.appearance import NCC_MEANS
from tracker.cmc import check_fields as check_cmc_fields
from tracker.pnmc.flow import SELECT_BY
from tracker.pnmc.queens import QUEEN_ORDERS

QUEEN_MODES: tuple[str, ...] = ("prominence", "random")
"""How queens are chosen: Algorithm 1, or at random, ``ceil(queen_fraction n)`` of them
(Algorithm 1's stopping count; Algorithm 1 itself may select more, since a cluster's features
are given back at once), the paper's Fig. 13 ablation "NMC with randomly initialised
queens"."""
NEIGHBOUR_WEIGHTS: tuple[str, ...] = ("previous", "updated")
"""The positions Eq. 3's weights measure (``PNMCParams.neighbour_weights``)."""


@dataclass(frozen=True, kw_only=True)
class PNMCParams:
    """Parameters of :class:`tracker.pnmc.tracker.PNMCTracker`.

    Attributes
    ----------
    search_factor : float
        Side of the search region of ``x_i^t`` in Eq. 8, template sizes (as the NCC baseline:
        2); the region is centred on the constant-velocity prediction ``A x_i^{t-1}``.
    tau : float
        ``tau``, threshold on the update confidence ``p(z^t | x_hat^t) = (gamma + 1) / 2``
        (Eq. 6, Algorithm 2, Sec. 4: 0.90). Below it the flow prior is tried, then the target
        goes to the back of the queue with its threshold lowered (delayed update).
    prior_sigma : float
        Standard deviation of every Gaussian of the NMC prior, ``A Sigma A^T = sigma^2 I``
        (Eq. 1-2), template sizes. The paper does not give a value.
    weight_scale : float
        Length unit of the neighbour weights ``w_j ~ exp(-||x_j - x_i|| / weight_scale)``
        (Eq. 3), px. The paper writes ``exp(-||x_j - x_i||)`` with positions in pixels: 1.
    neighbour_radius : float
        Radius of the neighbour graph ``G = (V, E)`` (Sec. 3.4, "neighbours within a fixed
        radius"), template sizes.
    neighbour_weights : str
        Which positions Eq. 3's weights ``w_j`` of the neighbours' Gaussians in ``p_N``
        measure. ``"previous"`` (default, kept so no figure moves): every neighbour's and the
        target's at ``t - 1``, once a frame, normalised over the target's neighbours.
        ``"updated"``: the paper's form (Sec. 3.2, Fig. 4: the target "at time t-1 ... its
        updated neighbors ... at time t"), ``||x_j^t - x_i^{t-1}||`` for each neighbour
        already updated, normalised over all its neighbours, those not yet updated at
        ``t - 1``. At ``weight_scale = 1`` px the weight goes mostly to the nearest
        neighbour, so the two can pick different neighbours to follow.
    ncc_mean : str
        What the likelihood's ``gamma`` (Eq. 7) takes off the template and the window before
        it correlates (:data:`tracker.appearance.NCC_MEANS`). ``"channel"`` (default, kept so
        no figure moves): each colour channel's own mean (OpenCV's ``TM_CCOEFF_NORMED``, as
        the NCC baseline), so a window that differs from the template by a constant in one
        channel scores 1. ``"joint"``: the paper's form, Eq. 7 correlating over x, y and
        colour with the template's mean subtracted, read as one mean over the patch's
        pixels and colours, so such a colour change lowers ``gamma``.
    use_neighbours : bool
        Use ``p_N`` (Eq. 2, 5). ``False``: every target is predicted by ``p_S`` alone (the
        paper's Fig. 13 "self component only").
    use_flow : bool
        Use the instantaneous-flow prior (Sec. 3.3) for low-confidence updates.
    n_clusters : int
        ``k``, components of the colour mixture (Sec. 4: 100).
    min_cluster_pixels : int
        Fewer pixels, fewer clusters: ``k <= (template pixels) / min_cluster_pixels``.
    queen_fraction : float
        Back-assignment stops once this fraction of templates is filled (Sec. 3.1: 10 %).
    fill_fraction : float
        Fraction of a template's pixels that makes it filled (Sec. 3.1: two thirds).
    queen_order : str
        Cluster sort criterion, ascending (Sec. 3.1: density ``m / v``); one of
        :data:`tracker.pnmc.queens.QUEEN_ORDERS`.
    queen_mode : str
        ``"prominence"`` (Algorithm 1) or ``"random"`` (``ceil(queen_fraction n)``, at least
        one, drawn at random: Algorithm 1's stopping count, not the number it selected).
    queen_every : int
        Queens are selected at the first frame and re-selected after targets were added, at
        most once every ``queen_every`` frames (Sec. 4: queens are selected "only when new
        initializations took place, which typically occurred after every fifty frames");
        targets added in between are not queens until the next selection.
    gmm_iterations : int
        Maximum EM iterations of the colour mixture.
    gmm_samples : int
        At most this many template pixels, drawn at random, fit the mixture (every pixel is
        then assigned to a component); bounds the cost of a selection.
    gmm_reg : float
        Covariance floor added to each ``Sigma`` of the mixture, (RGB units)^2.
    flow_patch : int
        Side of the instantaneous-flow patches, px (Sec. 3.3: 4).
    flow_spacing : int
        Grid spacing of the flow patches, px (Sec. 3.3: 4).
    flow_frames : int
        Frames over which each patch is tracked (Sec. 3.3: five); the velocity is the mean
        over the ``flow_frames - 1`` steps.
    flow_search : float
        Search radius of a flow patch per frame, template sizes.
    flow_radius : float
        Patches within this distance of ``x_i^{t-1}`` (by the position ``flow_select`` says)
        are the target's neighbours in the flow form of Eq. 2-3, template sizes.
    flow_select : str
        Which position of a patch's five-frame track picks the target's flow neighbours
        (:data:`tracker.pnmc.flow.SELECT_BY`); Eq. 3's weights use the patch's position in
        the frame before the newest either way. ``"start"`` (default, kept so no figure
        moves): where the track began, ``flow_frames - 2`` frames before ``x_i^{t-1}``'s
        frame (``flow_frames - 1`` before the newest). ``"last"``: the paper's form, the
        patch's position in the frame of ``x_i^{t-1}`` (Sec. 3.3: "we approximate the
        motion using nearby patches in an instantaneous flow field ... The selection of
        neighbors in Eq. (3) is now based on nearby patches instead of individuals"; Eq. 3
        measures ``||x_j - x_i||`` between positions, not a position and a place the
        neighbour left frames ago). ``"start"`` picks, for a fast target, the patches that
        were where it is now ``flow_frames - 2`` frames earlier (background, other people)
        and misses its own, which began
        ``(flow_frames - 2) |v|`` px back. Toy scene (a 12 px random-texture square moving
        -4 px/frame over static texture, ``tests/tracker/test_pnmc.py::
        test_flow_select_last_follows_a_fast_target``), the flow prior's patch-weighted
        mean x velocity over the 9 frames with a full buffer: -1.20 px/frame with
        ``"start"`` (none of the target's patches picked), -2.68 with ``"last"`` (its
        2 x 2 inner patches, exactly -4, among them), truth -4. What keeps ``"last"`` off
        -4 is Eq. 3's weighting at ``weight_scale = 1`` px, which gives most of the weight
        to the one or two patches nearest ``x_i^{t-1}``: here background tracks the
        square ran over, off the grid, with mixed velocities. ``"last"`` tracks the
        patches starting within ``flow_radius`` plus a track's reach (``sqrt(2)
        (flow_frames - 2) flow_search``: a disc 3.8 times ``flow_radius`` at the
        defaults), about 15 times as many cells for a lone target (fewer where targets'
        discs overlap); not timed on the bench crowds.
    flow_min_ncc : float
        A patch whose NCC falls below this in any of its steps (or that is flat) is dropped.
    update_every : int
        Frames between template refreshes (Sec. 4: 10).
    update_threshold : float
        A template is refreshed only when its update confidence ``(gamma + 1) / 2`` is at
        least this.
    seed : int
        Seed of the mixture initialisation and of random queens.
    lost_ratio, max_lost : float, int
        The track ends when its update confidence ``(gamma + 1) / 2`` stays below
        ``lost_ratio`` times its usual value for ``max_lost`` frames in a row (0 = only when
        it leaves the image).
    cmc : bool
        Camera-motion compensation (:mod:`tracker.cmc`; neither paper has one): before each
        frame's search, the global motion since the previous frame, estimated from the frames
        alone, moves the points and velocities (so the predictions ``A x_i^{t-1}``, the search
        regions and the neighbours' motions), and the flow prior's velocities lose the camera's
        mean motion over their frames (:class:`tracker.base.Tracker`). Off: the papers' static
        camera.
    cmc_method : str
        How that motion is estimated: ``"sparse"`` (BoT-SORT's sparse optical flow with a
        RANSAC similarity) or ``"ecc"`` (:data:`tracker.cmc.METHODS`).
    """

    search_factor: float = 2.0
    tau: float = 0.9
    prior_sigma: float = 0.5
    weight_scale: float = 1.0
    neighbour_radius: float = 2.5
    neighbour_weights: str = "previous"
    ncc_mean: str = "channel"
    use_neighbours: bool = True
    use_flow: bool = True
    n_clusters: int = 100
    min_cluster_pixels: int = 20
    queen_fraction: float = 0.1
    fill_fraction: float = 2.0 / 3.0
    queen_order: str = "density"
    queen_mode: str = "prominence"
    queen_every: int = 50
    gmm_iterations: int = 20
    gmm_samples: int = 5000
    gmm_reg: float = 1.0
    flow_patch: int = 4
    flow_spacing: int = 4
    flow_frames: int = 5
    flow_search: float = 0.5
    flow_radius: float = 0.75
    flow_select: str = "start"
    flow_min_ncc: float = 0.5
    update_every: int = 10
    update_threshold: float = 0.8
    seed: int = 0
    lost_ratio: float = 0.75
    max_lost: int = 5
    cmc: bool = False
    cmc_method: str = "sparse"

    def __post_init__(self) -> None:
        o = "PNMCParams"
        require_number(o, "search_factor", self.search_factor, lo=1, lo_open=True, hi=8)
        require_number(o, "tau", self.tau, lo=0, hi=1, hi_open=True)
        require_number(o, "prior_sigma", self.prior_sigma, lo=0, lo_open=True, hi=20)
        require_number(o, "weight_scale", self.weight_scale, lo=0, lo_open=True)
        require_number(o, "neighbour_radius", self.neighbour_radius, lo=0, hi=20)
        require_choice(o, "neighbour_weights", self.neighbour_weights, NEIGHBOUR_WEIGHTS)
        require_choice(o, "ncc_mean", self.ncc_mean, NCC_MEANS)
        require_choice(o, "use_neighbours", self.use_neighbours, (True, False))
        require_choice(o, "use_flow", self.use_flow, (True, False))
        require_number(o, "n_clusters", self.n_clusters, lo=1, hi=1_000, integer=True)
        require_number(
            o, "min_cluster_pixels", self.min_cluster_pixels, lo=1, hi=1_000_000, integer=True
        )
        require_number(o, "queen_fraction", self.queen_fraction, lo=0, hi=1, lo_open=True)
        require_number(o, "fill_fraction", self.fill_fraction, lo=0, hi=1, lo_open=True)
        require_choice(o, "queen_order", self.queen_order, QUEEN_ORDERS)
        require_choice(o, "queen_mode", self.queen_mode, QUEEN_MODES)
        require_number(o, "queen_every", self.queen_every, lo=1, integer=True)
        require_number(o, "gmm_iterations", self.gmm_iterations, lo=1, hi=1_000, integer=True)
        require_number(o, "gmm_samples", self.gmm_samples, lo=1, hi=1_000_000, integer=True)
        require_number(o, "gmm_reg", self.gmm_reg, lo=0, lo_open=True)
        require_number(o, "flow_patch", self.flow_patch, lo=2, hi=64, integer=True)
        require_number(o, "flow_spacing", self.flow_spacing, lo=1, hi=64, integer=True)
        require_number(o, "flow_frames", self.flow_frames, lo=2, hi=100, integer=True)
        require_number(o, "flow_search", self.flow_search, lo=0, lo_open=True, hi=8)
        require_number(o, "flow_radius", self.flow_radius, lo=0, lo_open=True, hi=8)
        require_choice(o, "flow_select", self.flow_select, SELECT_BY)
        require_number(o, "flow_min_ncc", self.flow_min_ncc, lo=-1, hi=1)
        require_number(o, "update_every", self.update_every, lo=1, integer=True)
        require_number(o, "update_threshold", self.update_threshold, lo=0, hi=1)
        require_number(o, "seed", self.seed, lo=0, hi=2**63, hi_open=True, integer=True)
        require_number(o, "lost_ratio", self.lost_ratio, lo=0, hi=1)
        require_number(o, "max_lost", self.max_lost, lo=0, integer=True)
        check_cmc_fields(o, self)
