"""Appearance models: exact shift recovery, batching, gated updates, edge cases."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from tracker.appearance import KCFAppearance, NCCAppearance, extract_patches, make_appearance
from tracker.testing import make_scene
from tracker.threads import in_chunks, max_threads, using_threads

MODELS = [
    KCFAppearance,
    NCCAppearance,
    lambda s, r, **kw: KCFAppearance(s, r, target_window=1.6, **kw),
]


def _shifted_scene():
    starts = [[30, 30], [70, 50], [100, 70]]
    vel = [[3, -2], [-4, 1], [0, 4]]
    return make_scene(starts, vel, n_frames=2, size=14), np.array(vel)


@pytest.mark.parametrize("cls", MODELS)
def test_peak_at_true_shift(cls):
    sc, vel = _shifted_scene()
    m = cls(14, 7)
    centers = sc.points[0].astype(np.int64)
    m.add(sc.frames[0], centers)
    s = m.scores(sc.frames[1], centers)
    assert s.shape == (3, 15, 15)
    iy, ix = np.unravel_index(s.reshape(3, -1).argmax(1), (15, 15))
    np.testing.assert_array_equal(np.c_[ix - 7, iy - 7], vel)
    # on the training frame the peak is at the centre
    s0 = m.scores(sc.frames[0], centers)
    assert (s0.reshape(3, -1).argmax(1) == 7 * 15 + 7).all()
    assert np.isfinite(s).all()


def test_kcf_gaussian_kernel_recovers_shift():
    sc, vel = _shifted_scene()
    m = KCFAppearance(14, 7, kernel="gaussian", target_window=1.6)
    centers = sc.points[0].astype(np.int64)
    m.add(sc.frames[0], centers)
    s = m.scores(sc.frames[1], centers)
    iy, ix = np.unravel_index(s.reshape(3, -1).argmax(1), (15, 15))
    np.testing.assert_array_equal(np.c_[ix - 7, iy - 7], vel)


def test_kcf_batch_equals_single_target_models():
    sc, _ = _shifted_scene()
    centers = sc.points[0].astype(np.int64)
    batch = KCFAppearance(14, 7)
    batch.add(sc.frames[0], centers)
    sb = batch.scores(sc.frames[1], centers)
    for i in range(3):
        single = KCFAppearance(14, 7)
        single.add(sc.frames[0], centers[i : i + 1])
        np.testing.assert_allclose(
            single.scores(sc.frames[1], centers[i : i + 1])[0], sb[i], rtol=1e-4, atol=1e-5
        )


@pytest.mark.parametrize("seed", range(4))
def test_kcf_models_grow_and_shrink_in_place_as_by_copies(seed):
    """Adding, ending (any subset, in order or not) and updating targets in any sequence
    leaves the models equal bit for bit to plain concatenation and indexing (the buffer
    with spare rows and the in-place compaction change no value); a deep copy of the model
    (as a branched tracker is) goes on independently of the original."""
    import copy

    rng = np.random.default_rng(seed)
    frame = rng.integers(0, 256, (90, 120, 3), dtype=np.uint8)
    model = KCFAppearance(10, 4)
    xf = np.zeros((0,) + model.xf.shape[1:], np.complex64)
    alphaf = np.zeros((0,) + model.alphaf.shape[1:], np.complex64)
    for _ in range(24):
        op = rng.integers(0, 4)
        if op == 0 or model.n == 0:
            centers = rng.integers(0, 100, (int(rng.integers(1, 7)), 2))
            probe = KCFAppearance(10, 4)
            probe.add(frame, centers)
            xf = np.concatenate([xf, probe.xf])
            alphaf = np.concatenate([alphaf, probe.alphaf])
            model.add(frame, centers)
        elif op == 1:
            index = np.flatnonzero(rng.random(model.n) < 0.7)
            xf, alphaf = xf[index], alphaf[index]
            model.keep(index)
        elif op == 2:
            index = rng.permutation(model.n)[: max(1, model.n // 2)]
            xf, alphaf = xf[index], alphaf[index]
            model.keep(index)
        else:
            model = copy.deepcopy(model)  # what branching a tracker does
        np.testing.assert_array_equal(model.xf, xf)
        np.testing.assert_array_equal(model.alphaf, alphaf)
    centers = rng.integers(0, 100, (model.n, 2))
    before = model.scores(frame, centers)
    branch = copy.deepcopy(model)
    branch.add(frame, centers[:2])
    branch.keep(np.arange(1, branch.n))
    np.testing.assert_array_equal(model.scores(frame, centers), before)


@pytest.mark.parametrize("cls", MODELS)
def test_update_only_when_confident(cls):
    sc, vel = _shifted_scene()
    centers = sc.points[0].astype(np.int64)
    m = cls(14, 7, update_threshold=0.6)
    m.add(sc.frames[0], centers)
    before = m.scores(sc.frames[0], centers).copy()
    for _ in range(12):  # NCC refreshes every 10 frames
        m.update(sc.frames[1], centers + vel, np.array([0.1, 0.59, 0.2]))
    np.testing.assert_allclose(m.scores(sc.frames[0], centers), before, atol=1e-6)
    for _ in range(12):
        m.update(sc.frames[1], centers + vel, np.array([0.9, 0.1, 0.1]))
    after = m.scores(sc.frames[0], centers)
    assert not np.allclose(after[0], before[0], atol=1e-4)
    np.testing.assert_allclose(after[1:], before[1:], atol=1e-6)


def test_ncc_updates_every_ten_frames():
    sc, vel = _shifted_scene()
    centers = sc.points[0].astype(np.int64)
    m = NCCAppearance(14, 7, update_every=10)
    m.add(sc.frames[0], centers)
    t0 = m.templates.copy()
    for _ in range(9):
        m.update(sc.frames[1], centers + vel, np.ones(3))
    np.testing.assert_array_equal(m.templates, t0)
    m.update(sc.frames[1], centers + vel, np.ones(3))
    assert not np.array_equal(m.templates, t0)
    np.testing.assert_array_equal(m.age, 0)


@pytest.mark.parametrize("cls", MODELS)
def test_empty_frame_zero_targets_and_border(cls):
    m = cls(8, 4)
    flat = np.full((40, 50, 3), 90, np.uint8)
    assert m.scores(flat, np.zeros((0, 2))).shape == (0, 9, 9)
    m.add(flat, np.array([[0, 0], [49, 39], [25, 20]]))  # corners: replicated border
    s = m.scores(flat, np.array([[0, 0], [49, 39], [25, 20]]))
    assert s.shape == (3, 9, 9) and np.isfinite(s).all()
    m.keep(np.array([2]))
    assert m.n == 1


@pytest.mark.parametrize("size", [3, 8, 20])
@pytest.mark.parametrize("channels", [3, 1, 4])
def test_kcf_windows_are_extract_patches_centred_and_windowed_as_numpy(size, channels):
    """The compiled KCF windows are extract_patches as float32 (border replicated, corners far
    outside the frame clipped as there; the colour frames' path and the general one), less
    numpy's float32 mean (its pairwise sums), times the window: numpy's ``x -= mean;
    x *= window`` bit for bit, so the features, and the tracks, are those of the three numpy
    passes the one pass replaced."""
    from tracker.appearance import _window_patches, hann2d, pairwise_plan

    rng = np.random.default_rng(4)
    frame = rng.integers(0, 256, (11, 13, channels), dtype=np.uint8)
    corners = np.array([[-1, -1], [3, 2], [10, 9], [-40, 5], [30, -25], [12, 10], [0, 0]])
    # flush with the right edge, and one column past it (inside / clamped column paths)
    corners = np.concatenate([corners, [[13 - size, 1], [14 - size, 1]]])
    window = hann2d(size) * np.float32(1 / 255)
    out = np.empty((len(corners), channels, size, size), np.float32)
    blocks, adds = pairwise_plan(size * size)
    work = np.empty((len(corners), len(blocks) + len(adds)), np.float32)
    _window_patches(frame, corners, size, window, blocks, adds, work, out)
    ref = extract_patches(frame, corners, size).astype(np.float32)
    ref -= ref.reshape(len(corners), channels, -1).mean(axis=2)[:, :, None, None]
    ref *= window
    np.testing.assert_array_equal(out, ref)


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_numpy_sum_of_a_segment_is_numpys_sum_bit_for_bit(dtype):
    """:func:`tracker.appearance.numpy_sum` (compiled code that must give numpy's value, e.g.
    PNMC's flow weights) sums a segment as numpy sums it: in order under 8 values, eight
    accumulators up to 128, halves (multiples of 8) above, at any offset into the array."""
    from tracker.appearance import numpy_sum

    rng = np.random.default_rng(3)
    lengths = [*range(0, 140), 255, 256, 257, 300, 1000, 1024, 1031, 4096, 10_007, 100_003]
    for n in lengths:
        lo = int(rng.integers(0, 9))
        a = (rng.standard_normal(n + 9) * 10.0 ** rng.uniform(-3, 3, n + 9)).astype(dtype)
        got = dtype(numpy_sum(a, lo, n))  # numba hands back a Python float
        assert got.tobytes() == a[lo : lo + n].sum().tobytes(), n


@pytest.mark.parametrize("n", [1, 7, 8, 9, 64, 128, 129, 300, 400, 576, 1296, 4096])
def test_pairwise_sum_is_numpys_float32_sum(n):
    """The windows' means sum as numpy does (pairwise, eight accumulators), bit for bit, on
    every path: under 8 values, up to 128, and halved above."""
    from tracker.appearance import _pairwise_sum, pairwise_plan

    rng = np.random.default_rng(n)
    plan = pairwise_plan(n)
    for scale in (1.0, 255.0, 1e6):
        a = (rng.standard_normal(n + 3) * scale).astype(np.float32)[3:]
        assert _pairwise_sum(a, *plan) == a.sum()
        a = np.round(rng.random(n) * 255).astype(np.float32)  # pixel values
        assert _pairwise_sum(a, *plan) == a.sum()


def test_kcf_cross_spectrum_divides_as_numpy_does_bit_for_bit():
    """The linear kernel's division by ``numel`` inside the compiled cross-spectrum pass is
    numpy's ``complex64 / float32`` bit for bit, signed zeros included (numpy divides by a
    complex number with a zero imaginary part), so the scores are those of the two passes
    it replaced; ``scale = 0`` leaves the sum undivided (the Gaussian kernel's path)."""
    from tracker.appearance import _cross_spectrum

    rng = np.random.default_rng(6)

    def spectra(*shape):
        v = rng.standard_normal(shape) + 1j * rng.standard_normal(shape)
        v[..., :3] = 0.0  # zero products, whose signs the division may flip
        v[..., 3] = -0.0 - 0.0j
        return v.astype(np.complex64)

    xf, zf = spectra(20, 3, 64), spectra(20, 3, 64)
    # conj(1 - 0j) (-0 + 1j) = -0 + 1j in every channel: a sum of -0 + 3j, which numpy's
    # division turns into +0 + ...j ((-0 + 3 * 0) / numel)
    xf[:, :, 5] = np.complex64(complex(1.0, -0.0))
    zf[:, :, 5] = np.complex64(complex(-0.0, 1.0))
    total = np.empty((20, 64), np.complex64)
    _cross_spectrum(xf, zf, total, np.float32(0.0))
    want = np.conj(xf[:, 0]) * zf[:, 0]
    for c in (1, 2):
        want += np.conj(xf[:, c]) * zf[:, c]
    np.testing.assert_allclose(total, want, rtol=1e-5, atol=1e-5)  # undivided: the sum
    numel = np.float32(24 * 24 * 3)
    divided = np.empty((20, 64), np.complex64)
    _cross_spectrum(xf, zf, divided, numel)
    np.testing.assert_array_equal(divided.view(np.uint64), (total / numel).view(np.uint64))
    assert np.signbit(total.real[:, 5]).all() and not np.signbit(divided.real[:, 5]).any()


def test_extract_patches_replicates_border():
    f = np.arange(12, dtype=np.uint8).reshape(3, 4, 1)
    p = extract_patches(f, np.array([[-1, -1], [3, 2]]), 3)
    assert p.shape == (2, 1, 3, 3)
    np.testing.assert_array_equal(p[0, 0], [[0, 0, 1], [0, 0, 1], [4, 4, 5]])
    np.testing.assert_array_equal(p[1, 0, 0], [11, 11, 11])


def test_bad_arguments():
    with pytest.raises(ValueError, match="template_size"):
        KCFAppearance(1, 3)
    with pytest.raises(ValueError, match="unknown appearance"):
        make_appearance("hog", 8, 4, update_threshold=0.6)
    m = KCFAppearance(8, 4)
    with pytest.raises(ValueError, match="uint8"):
        m.add(np.zeros((10, 10)), np.zeros((1, 2)))
    m.add(np.zeros((10, 10, 3), np.uint8), np.array([[5, 5]]))
    with pytest.raises(ValueError, match="centres"):
        m.scores(np.zeros((10, 10, 3), np.uint8), np.zeros((2, 2)))


@pytest.mark.parametrize("n", [0, 1, 31, 64, 65, 1000])
def test_in_chunks_covers_every_item_once(n):
    seen = np.zeros(n, np.int64)

    def work(lo, hi):
        seen[lo:hi] += 1

    with using_threads(max_threads()):
        in_chunks(n, work, min_per_thread=16)
    np.testing.assert_array_equal(seen, 1)


def test_in_chunks_reraises_a_chunk_error():
    def work(lo, hi):
        if lo > 0:
            raise ValueError(f"chunk {lo}")

    with using_threads(max_threads()), pytest.raises(ValueError, match="chunk"):
        in_chunks(400, work, min_per_thread=1)
        if max_threads() == 1:  # one chunk starts at 0: nothing to re-raise on one core
            raise ValueError("chunk (one core)")


def test_ncc_scores_same_for_any_thread_count():
    rng = np.random.default_rng(3)
    frame = rng.integers(0, 256, (240, 320, 3), dtype=np.uint8)
    centers = rng.integers(10, 230, (150, 2))
    m = NCCAppearance(10, 5)
    m.add(frame, centers)
    moved = np.clip(centers + rng.integers(-2, 3, centers.shape), 0, 239)
    out = []
    for threads in sorted({1, max_threads()}):
        with using_threads(threads):
            out.append(m.scores(frame, moved))
    for o in out[1:]:
        np.testing.assert_array_equal(o, out[0])


@pytest.mark.parametrize("kernel", ["linear", "gaussian"])
def test_kcf_numpy_passes_in_chunks_are_one_calls(kernel, monkeypatch):
    """The means, the training division and the crop of the responses, run in row chunks on
    two threads, equal the one-call numpy expressions they replace, bit for bit."""
    import scipy.fft

    import tracker.appearance as appearance

    if max_threads() < 2:
        pytest.skip("needs 2 cores")
    monkeypatch.setattr(appearance, "ROWS_PER_THREAD", 7)
    rng = np.random.default_rng(4)
    frame = rng.integers(0, 256, (240, 320, 3), dtype=np.uint8)
    centers = rng.integers(10, 310, (90, 2))
    centers[:, 1] %= 230
    m = KCFAppearance(12, 6, kernel=kernel, target_window=1.6)
    with using_threads(2):
        m.add(frame, centers)
        xf = m._features(frame, centers, train=True)
        alphaf = m._train(xf)
        got = m.scores(frame, centers + 1)
    w = m.window
    x = extract_patches(frame, centers - w // 2, w).astype(np.float32)
    x -= x.reshape(90, 3, -1).mean(axis=2)[..., None, None]  # one numpy call, all rows
    x *= m._train_window
    np.testing.assert_array_equal(xf, scipy.fft.rfft2(x, axes=(-2, -1)))
    expected = (m._yf / (m._kernel_f(xf, xf) + np.float32(m.lam))).astype(np.complex64)
    np.testing.assert_array_equal(alphaf, expected)
    zf = m._features(frame, centers + 1)
    resp = scipy.fft.irfft2(m.alphaf * m._kernel_f(m.xf, zf), s=(w, w), axes=(-2, -1))
    c, r = w // 2, m.radius
    np.testing.assert_array_equal(got, resp[:, c - r : c + r + 1, c - r : c + r + 1])


def test_kcf_updates_at_exactly_the_threshold():
    """A confidence equal to update_threshold refreshes the KCF model; one just below does not."""
    rng = np.random.default_rng(0)
    a = rng.integers(0, 256, (48, 48, 3), dtype=np.uint8)
    b = rng.integers(0, 256, (48, 48, 3), dtype=np.uint8)
    centers = np.array([[24, 24], [20, 26]])
    m = KCFAppearance(8, 3, update_threshold=0.6)
    m.add(a, centers)
    xf0, alphaf0 = m.xf.copy(), m.alphaf.copy()
    m.update(b, centers, np.array([0.6, np.nextafter(0.6, 0.0)]))
    assert not np.array_equal(m.xf[0], xf0[0]) and not np.array_equal(m.alphaf[0], alphaf0[0])
    np.testing.assert_array_equal(m.xf[1], xf0[1])
    np.testing.assert_array_equal(m.alphaf[1], alphaf0[1])


# ---------------------------------------------------------------- flat patches (0 / 0)


def _flat_on_textured(value=(90, 90, 90)):
    """A textured frame with a flat square; the first centre's template and window lie in it,
    the second's on texture."""
    rng = np.random.default_rng(5)
    frame = rng.integers(0, 256, (60, 80, 3), dtype=np.uint8)
    frame[5:35, 5:35] = value
    return frame, np.array([[20, 20], [60, 40]])


@pytest.mark.parametrize("value", [(90, 90, 90), (10, 20, 30)])
def test_ncc_flat_template_scores_zero_not_one_everywhere(value):
    """A template with no texture (each channel constant) is no evidence: every offset of the
    textured frame scores exactly 0 (OpenCV's TM_CCOEFF_NORMED gave 1 at every offset), and
    the textured target beside it keeps OpenCV's scores bit for bit."""
    frame, centers = _flat_on_textured(value)
    m = NCCAppearance(8, 4)
    m.add(frame, centers)
    textured = np.random.default_rng(6).integers(0, 256, frame.shape, dtype=np.uint8)
    textured[30:, 40:] = frame[30:, 40:]
    s = m.scores(textured, centers)
    np.testing.assert_array_equal(s[0], np.zeros((9, 9), np.float32))
    win = np.ascontiguousarray(textured[32:48, 52:68])
    np.testing.assert_array_equal(
        s[1], cv2.matchTemplate(win, m.templates[1], cv2.TM_CCOEFF_NORMED)
    )
    assert s[1, 4, 4] == pytest.approx(1.0, abs=1e-6)


def test_ncc_joint_mean_flat_only_where_every_value_is_equal():
    """One mean over colours: a constant colour (10, 20, 30) still varies, a grey one does
    not. The grey template scores 0 everywhere, the coloured one a correlation coefficient of
    its colour pattern; the per-channel mean scores both 0."""
    rng = np.random.default_rng(7)
    textured = rng.integers(0, 256, (60, 80, 3), dtype=np.uint8)
    grey, c = _flat_on_textured((90, 90, 90))
    colour, _ = _flat_on_textured((10, 20, 30))
    for frame, joint_flat in ((grey, True), (colour, False)):
        for mean in ("channel", "joint"):
            m = NCCAppearance(8, 4, mean=mean)
            m.add(frame, c[:1])
            s = m.scores(textured, c[:1])
            assert np.isfinite(s).all() and (np.abs(s) <= 1).all()
            assert (s == 0).all() == (mean == "channel" or joint_flat)


def test_ncc_blank_frame_scores_zero_and_finite():
    """Template and window both black (0 / 0): exactly 0 at every offset for either mean, and
    a textured template over the black frame 0 too; never 1, NaN or inf."""
    black = np.zeros((40, 50, 3), np.uint8)
    tex = np.random.default_rng(8).integers(0, 256, black.shape, dtype=np.uint8)
    centers = np.array([[25, 20], [0, 0]])  # the second partly outside: replicated border
    for mean in ("channel", "joint"):
        for first in (black, tex):
            m = NCCAppearance(8, 4, mean=mean)
            m.add(first, centers)
            got = m.scores(black, centers)
            np.testing.assert_array_equal(got, np.zeros((2, 9, 9), np.float32))


def test_window_spread_and_template_spread_exact_on_a_hand_built_patch():
    """A 3 x 3 window, black but (0, 0, 6) at its top-left pixel, and 2 x 2 patches: only the
    top-left patch varies, by 36 - 6^2 / 4 = 27 about each channel's mean and by 36 - 6^2 / 12
    = 33 about the one mean."""
    from tracker.appearance import _window_spread, template_spread

    w = np.zeros((1, 3, 3, 3), np.uint8)
    w[0, 0, 0] = (0, 0, 6)
    for per_channel, v in ((True, 27.0), (False, 33.0)):
        out = np.full((1, 2, 2), np.nan)
        _window_spread(w, 2, 2, per_channel, out)
        np.testing.assert_array_equal(out, [[[v, 0.0], [0.0, 0.0]]])
        np.testing.assert_array_equal(template_spread(w[:, :2, :2], per_channel), [v])
        np.testing.assert_array_equal(template_spread(w[:, 1:, 1:], per_channel), [0.0])


@pytest.mark.parametrize(("name", "no_evidence"), [("ncc", 0.0), ("pnmc", 0.5), ("bqp-ncc", 0.0)])
def test_tracker_with_a_flat_template_reports_no_evidence_and_stays(name, no_evidence):
    """A target whose template is flat, on a textured frame: every candidate scores alike, so
    it stays where it was, and its confidence is that of no evidence (NCC 0; PNMC's
    likelihood (0 + 1) / 2), not that of a perfect match (1)."""
    from tracker.registry import make_tracker

    frame, centers = _flat_on_textured()
    tex = np.random.default_rng(9).integers(0, 256, frame.shape, dtype=np.uint8)
    if name == "bqp-ncc":
        t = make_tracker("bqp", appearance="ncc")
    else:
        t = make_tracker(name)
    t.init(frame, [1], centers[:1].astype(float), 8)
    ids, pts = t.step(tex)
    assert ids.tolist() == [1]
    np.testing.assert_array_equal(pts, centers[:1])
    assert t.confidence.tolist() == [no_evidence]
