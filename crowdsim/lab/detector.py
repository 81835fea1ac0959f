"""Train and evaluate the head-point detector on our own synthetic crowds.

Data (:func:`training_specs`, :func:`heldout_specs`)
    Every sequence is simulated and rendered in memory through the writer's camera path (H.264
    and JPEG included), so the network sees exactly the frames a tracker reads. Three kinds:

    * ``default``: every scenario at the renderer's default appearance, 8-16 px heads;
    * ``hard``: the tuning environment's hard appearance (low contrast, strong noise, look-alike
      clothing) plus the calibration's difficulty scale drawn in ``[0, 0.9]`` (packing, head
      turns, clutter, blur, compression; :func:`crowdsim.knobs.knob_values`);
    * ``ucf9``: the calibrated ``ucf9`` and ``ucf9-drone`` specs with *other* seeds than their
      own (new crowds, new clothing, new clutter on the same scenes).

    Held-out sets never share a seed with training (checked): ``default`` and ``hard`` are drawn
    from a fixed evaluation seed, ``ucf9`` is the suite at its own seeds, the ones every table
    of this project uses.

Training (:func:`train`)
    CenterNet's penalty-reduced focal loss on the heat map and an L1 loss on the sub-cell
    offsets (:mod:`tracker.detect.model`), AdamW with a warm-up and a cosine schedule, random
    crops with the eight rotations and flips of the top-down view and a random rescale
    (0.75-1.33: heads of 6-21 px). Every batch is drawn from ``(seed, iteration)`` and the
    schedule is a function of the iteration, so a run stopped and resumed from its checkpoint
    gives the same weights as one that never stopped.

Evaluation (:func:`evaluate`)
    Precision, recall and F1 of one-to-one matches within 5 px and the mean localisation error,
    per kind and per scene or difficulty level, for the network and the classical LoG baseline
    (:class:`tracker.detect.classical.LogDetector`, its threshold fitted on the training frames,
    and given each sequence's true head size, which the network is not).
"""

from __future__ import annotations

import json
import os
import time
from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor
from dataclasses import asdict, dataclass, fields, replace
from pathlib import Path
from typing import Any

import numpy as np

from crowdsim.atomic import holds_only_leftovers
from crowdsim.checks import require_number

EVAL_SEED = 20261126
"""Root seed of the held-out ``default`` and ``hard`` sequences (never used for training)."""
KINDS = ("default", "hard", "ucf9")
TEMPLATES = tuple(range(8, 17))
"""Head sizes of the generated sequences, px (the papers' sequences: 8-16)."""
MARKER = ".crowdsim-detector.json"
"""The file that marks a training folder as this program's (and holds its settings)."""
TRAIN_OUTPUTS: tuple[str, ...] = ("head_points.pt", "head_points.json", "loss.png")
"""What :func:`train` writes into its folder (besides the marker and, while running, the
checkpoint); their digests go into the folder's ledger."""


@dataclass(frozen=True, kw_only=True)
class TrainConfig:
    """Settings of one training run (recorded beside the weights).

    Attributes
    ----------
    seed : int
        Seed of the data draws, the initial weights and every batch.
    sequences : int
        Generated training sequences (shared out over the kinds by :data:`MIX`).
    frames_per_sequence : int
        Frames taken from each sequence (12 frames apart: the crowd moves between them).
    iterations : int
        Optimiser steps.
    batch : int
        Crops per step.
    crop : int
        Crop side, px (a multiple of the network's stride).
    lr : float
        Peak learning rate (AdamW).
    checkpoint_every : int
        Steps between checkpoints (resumable training).
    """

    seed: int = 0
    sequences: int = 300
    frames_per_sequence: int = 3
    iterations: int = 4000
    batch: int = 16
    crop: int = 160
    lr: float = 3e-3
    checkpoint_every: int = 250

    def __post_init__(self) -> None:
        own = "TrainConfig"
        require_number(own, "seed", self.seed, lo=0, hi=2**31 - 1, integer=True)
        require_number(own, "sequences", self.sequences, lo=len(MIX), hi=100_000, integer=True)
        require_number(
            own, "frames_per_sequence", self.frames_per_sequence, lo=1, hi=20, integer=True
        )
        require_number(own, "iterations", self.iterations, lo=1, hi=10_000_000, integer=True)
        require_number(own, "batch", self.batch, lo=1, hi=1024, integer=True)
        require_number(own, "crop", self.crop, lo=32, hi=1024, integer=True)
        if self.crop % 4:
            raise ValueError(f"TrainConfig.crop must be a multiple of 4, got {self.crop}")
        require_number(own, "lr", self.lr, lo=0, hi=1, lo_open=True)
        require_number(own, "checkpoint_every", self.checkpoint_every, lo=1, integer=True)


MIX: dict[str, float] = {"default": 0.3, "hard": 0.4, "ucf9": 0.3}
"""Share of each kind in the training sequences."""

FRAME_GAP = 12
"""Frames between the frames taken from one sequence."""


# ---------------------------------------------------------------------------------- specs
def _distribution(kind: str) -> Any:
    from envs.episodes import ScenarioDistribution

    if kind == "default":
        return ScenarioDistribution(template_px=TEMPLATES, difficulty=(0.0, 0.0))
    return ScenarioDistribution(template_px=TEMPLATES, difficulty=(0.0, 0.9))


def _drawn_spec(kind: str, rng: np.random.Generator, name: str) -> Any:
    from crowdsim.appearance_model import AppearanceParams

    spec = _distribution(kind).sample_spec(rng, name=name)
    if kind == "default":  # the renderer's default look at the drawn head size
        app = AppearanceParams(template_px=spec.appearance.template_px)
        spec = replace(spec, appearance=app, description=spec.description.split(", difficulty")[0])
    return spec


def _suite_pool() -> list[Any]:
    from synth_data.suites import suite_specs

    return list(suite_specs("ucf9")) + list(suite_specs("ucf9-drone"))


def _frames_needed(spec: Any, n: int) -> Any:
    return spec.truncated(min(spec.frames, 1 + FRAME_GAP * (n - 1)))


def heldout_specs(per_kind: int = 9) -> list[tuple[str, str, Any]]:
    """``[(kind, group, spec)]`` of the held-out evaluation sequences.

    ``group`` is the scene (``default``: the scenario), the difficulty level (``hard``: the
    drawn difficulty in thirds) or the sequence (``ucf9``: the suite at its own seeds).
    """
    from synth_data.suites import suite_specs

    out: list[tuple[str, str, Any]] = []
    for kind in ("default", "hard"):
        rng = np.random.default_rng([EVAL_SEED, KINDS.index(kind)])
        for i in range(per_kind):
            spec = _drawn_spec(kind, rng, f"heldout-{kind}-{i}")
            out.append((kind, _group(kind, spec), spec))
    for spec in suite_specs("ucf9"):
        out.append(("ucf9", spec.name, spec))
    return out


def _group(kind: str, spec: Any) -> str:
    if kind == "default":
        return str(spec.scenario["name"])
    d = (
        float(spec.description.rsplit("difficulty", 1)[1])
        if "difficulty" in spec.description
        else 0
    )
    return (
        "difficulty 0-0.3" if d < 0.3 else "difficulty 0.3-0.6" if d < 0.6 else "difficulty 0.6-0.9"
    )


def training_specs(config: TrainConfig) -> list[tuple[str, Any]]:
    """``[(kind, spec)]`` of the training sequences: :data:`MIX` of the kinds, every seed
    different from the held-out ones (``ValueError`` otherwise, which would be a bug)."""
    rng = np.random.default_rng([config.seed, 1])
    counts = {k: int(round(share * config.sequences)) for k, share in MIX.items()}
    counts["hard"] += config.sequences - sum(counts.values())
    pool = _suite_pool()
    out: list[tuple[str, Any]] = []
    for kind, n in counts.items():
        for i in range(n):
            if kind == "ucf9":
                base = pool[i % len(pool)]
                seed = int(rng.integers(10_000, 2**31 - 1))
                spec = replace(base, seed=seed, name=f"train-{base.name}-{i}")
            else:
                spec = _drawn_spec(kind, rng, f"train-{kind}-{i}")
            out.append((kind, spec))
    held = {s.seed for _, _, s in heldout_specs()}
    clash = [s.name for _, s in out if s.seed in held]
    if clash:
        raise ValueError(f"training sequences {clash[:3]} share a seed with the held-out set")
    return out


# ---------------------------------------------------------------------------------- frames
@dataclass
class Sample:
    """One frame with its heads: ``frame (H, W, 3)`` uint8, ``points (k, 2)`` px."""

    frame: np.ndarray
    points: np.ndarray
    template_px: int
    kind: str = ""
    group: str = ""
    name: str = ""


def spec_samples(spec: Any, n_frames: int, kind: str = "", group: str = "") -> list[Sample]:
    """Render ``spec`` in memory and take ``n_frames`` frames :data:`FRAME_GAP` apart."""
    from synth_data.sequence import InMemorySequence

    spec = _frames_needed(spec, n_frames)
    seq = InMemorySequence.from_spec(spec, camera_output=True)
    _, pts = seq.gt_points()
    out = []
    for t, frame in enumerate(seq.frames()):
        if t % FRAME_GAP or len(out) >= n_frames:
            continue
        p = pts[t][np.isfinite(pts[t]).all(1)]
        h, w = frame.shape[:2]
        p = p[(p[:, 0] >= 0) & (p[:, 0] <= w - 1) & (p[:, 1] >= 0) & (p[:, 1] <= h - 1)]
        out.append(Sample(frame, p, int(seq.template_size), kind, group, spec.name))
    return out


def _spec_samples_job(args: tuple[Any, int, str, str]) -> list[Sample]:
    return spec_samples(*args)


def render_samples(
    jobs: Sequence[tuple[Any, int, str, str]],
    workers: int = 1,
    progress: bool = True,
    desc: str = "",
) -> list[Sample]:
    """:func:`spec_samples` of every ``(spec, n_frames, kind, group)``, in order, on
    ``workers`` processes, with a progress bar."""
    from crowdsim.progress import progress_bar

    bar = progress_bar(total=len(jobs), desc=desc or "render", unit="seq", enabled=progress)
    out: list[Sample] = []
    try:
        if workers <= 1:
            for job in jobs:
                out += _spec_samples_job(job)
                bar.update(1)
        else:
            with ProcessPoolExecutor(workers) as pool:
                for got in pool.map(_spec_samples_job, jobs, chunksize=2):
                    out += got
                    bar.update(1)
    finally:
        bar.close()
    return out


# ---------------------------------------------------------------------------------- batches
def _augment(frame: np.ndarray, pts: np.ndarray, rng: np.random.Generator, crop: int):
    """A random crop of ``crop`` px (padded with the frame's mean colour where the frame is
    smaller), rescaled, rotated by a multiple of 90 degrees and maybe mirrored."""
    import cv2

    scale = float(np.exp(rng.uniform(np.log(0.75), np.log(1.333)))) if rng.random() < 0.5 else 1.0
    src = int(np.ceil(crop / scale))
    h, w = frame.shape[:2]
    x0 = int(rng.integers(min(0, w - src), max(0, w - src) + 1))
    y0 = int(rng.integers(min(0, h - src), max(0, h - src) + 1))
    fill = frame.reshape(-1, 3).mean(0)
    patch = np.empty((src, src, 3), np.uint8)
    patch[:] = fill.astype(np.uint8)
    sx0, sy0 = max(x0, 0), max(y0, 0)
    sx1, sy1 = min(x0 + src, w), min(y0 + src, h)
    patch[sy0 - y0 : sy1 - y0, sx0 - x0 : sx1 - x0] = frame[sy0:sy1, sx0:sx1]
    p = pts - [x0, y0]
    if src != crop:
        f = crop / src
        patch = cv2.resize(
            patch, (crop, crop), interpolation=cv2.INTER_AREA if f < 1 else cv2.INTER_LINEAR
        )
        p = (p + 0.5) * f - 0.5
    keep = (p >= -0.5).all(1) & (p < crop - 0.5).all(1)
    p = p[keep]
    k = int(rng.integers(4))
    for _ in range(k):  # rotate 90 degrees counter-clockwise: (x, y) -> (y, crop-1-x)
        patch = np.rot90(patch)
        p = np.stack([p[:, 1], crop - 1 - p[:, 0]], axis=1)
    if rng.random() < 0.5:
        patch = patch[:, ::-1]
        p = np.stack([crop - 1 - p[:, 0], p[:, 1]], axis=1)
    return np.ascontiguousarray(patch), p, scale


def make_batch(samples: Sequence[Sample], rng: np.random.Generator, batch: int, crop: int):
    """``(x (B, 3, crop, crop) float32, heat (B, h, w), offsets list, cells list)``."""
    from tracker.detect.model import STRIDE, standardise, targets

    out_hw = crop // STRIDE
    idx = rng.integers(len(samples), size=batch)
    patches, heats, cells, offs = [], [], [], []
    for i in idx:
        s = samples[int(i)]
        patch, p, scale = _augment(s.frame, s.points, rng, crop)
        heat, c, o = targets(p, out_hw, out_hw, s.template_px * scale)
        patches.append(patch)
        heats.append(heat)
        cells.append(c)
        offs.append(o)
    return standardise(np.stack(patches)), np.stack(heats), cells, offs


def _loss(torch: Any, out: Any, heat: Any, cells: list, offs: list) -> tuple[Any, float, float]:
    """CenterNet's focal loss (alpha 2, beta 4) plus the L1 offset loss, per head."""
    logit = out[:, 0]
    pos = heat >= 1.0
    log_p = torch.nn.functional.logsigmoid(logit)
    log_1p = torch.nn.functional.logsigmoid(-logit)
    p = torch.sigmoid(logit)
    pos_l = (log_p * (1 - p) ** 2)[pos].sum()
    neg_l = (log_1p * p**2 * (1 - heat) ** 4)[~pos].sum()
    n_pos = max(int(pos.sum()), 1)
    focal = -(pos_l + neg_l) / n_pos
    b = np.concatenate([np.full(len(c), i) for i, c in enumerate(cells)]).astype(np.int64)
    c = np.concatenate(cells).reshape(-1, 2)
    o = np.concatenate(offs).reshape(-1, 2)
    if len(c):
        pred = out[torch.from_numpy(b), 1:3, torch.from_numpy(c[:, 0]), torch.from_numpy(c[:, 1])]
        off_l = (pred - torch.from_numpy(o)).abs().sum() / n_pos
    else:
        off_l = out.sum() * 0.0
    return focal + off_l, float(focal.detach()), float(off_l.detach())


def _lr(config: TrainConfig, it: int) -> float:
    warm = max(1, config.iterations // 20)
    if it < warm:
        return float(config.lr * (it + 1) / warm)
    q = (it - warm) / max(1, config.iterations - warm)
    return float(config.lr * 0.5 * (1 + np.cos(np.pi * q)))


# ---------------------------------------------------------------------------------- training
def _check_out(out: Path, config: TrainConfig) -> dict | None:
    """The folder's earlier run (its marker), ``None`` for a new or empty folder; refuses a
    folder this program did not make or one made with other settings."""
    if out.exists() and not out.is_dir():
        raise ValueError(f"--out {out}: is a file, not a folder")
    marker = out / MARKER
    if marker.is_file():
        try:
            earlier = json.loads(marker.read_text())
        except (OSError, ValueError) as exc:
            raise ValueError(f"{marker}: unreadable ({exc}); use a new --out folder") from None
        if earlier.get("config") != asdict(config):
            raise ValueError(
                f"--out {out} holds a training run with other settings "
                f"({earlier.get('config')}); give the same settings to resume, or a new folder"
            )
        return earlier
    if out.is_dir() and not holds_only_leftovers(out):
        raise ValueError(
            f"--out {out} is a folder that this program did not make (no {MARKER}); "
            "give a new or empty folder"
        )
    return None


def train(
    out: str | os.PathLike[str],
    config: TrainConfig | None = None,
    *,
    workers: int = 1,
    progress: bool = True,
    command: str = "",
    log: Callable[[str], None] = print,
    overwrite: bool = False,
) -> dict[str, Any]:
    """Train the detector into folder ``out``; resumes from its checkpoint when there is one.

    Writes ``head_points.pt`` (weights), ``head_points.json`` (the command, the data, the
    settings, the losses), ``loss.png`` and, while running, ``checkpoint.pt``. Returns the
    JSON record. Their digests go into the folder's ledger (:mod:`crowdsim.atomic`): a file
    of those names that this program cannot prove it wrote (a user's, or one edited since)
    is refused before any work unless ``overwrite`` (a folder from before the ledger, with
    this program's marker and no ledger, vouches for its own).
    """
    from crowdsim.atomic import LEDGER, recorded, require_replaceable, write_text_atomic
    from crowdsim.optional import require
    from crowdsim.progress import progress_bar
    from tracker.detect.inference import save_weights
    from tracker.detect.model import Architecture, build_net

    torch = require("torch", "detect", "crowdsim detector train")
    config = config or TrainConfig()
    out = Path(out)
    _check_out(out, config)
    outputs = [out / name for name in TRAIN_OUTPUTS]
    if not ((out / MARKER).is_file() and not (out / LEDGER).exists()):
        for path in outputs:
            require_replaceable("--out", path, overwrite)
    out.mkdir(parents=True, exist_ok=True)
    write_text_atomic(out / MARKER, json.dumps({"config": asdict(config)}, indent=1))

    ckpt = out / "checkpoint.pt"
    # read before the minutes of rendering the training data, so that a damaged or foreign
    # checkpoint is named at once (the network is built after: the render workers fork)
    state = _read_checkpoint(torch, ckpt) if ckpt.is_file() else None

    t0 = time.perf_counter()
    specs = training_specs(config)
    jobs = [(s, config.frames_per_sequence, k, "") for k, s in specs]
    samples = render_samples(jobs, workers=workers, progress=progress, desc="training data")
    data_s = time.perf_counter() - t0
    n_heads = int(sum(len(s.points) for s in samples))
    log(
        f"training data: {len(samples)} frames of {len(specs)} sequences, {n_heads} heads, "
        f"{data_s:.0f} s"
    )

    torch.manual_seed(config.seed)
    arch = Architecture()
    net = build_net(arch).to(memory_format=torch.channels_last)
    opt = torch.optim.AdamW(net.parameters(), lr=config.lr, weight_decay=1e-4)
    history: list[list[float]] = []
    start = 0
    if state is not None:
        try:
            net.load_state_dict(state["net"])
            opt.load_state_dict(state["opt"])
        except (RuntimeError, ValueError, KeyError) as exc:  # another network's shapes
            lines = [ln.strip() for ln in str(exc).splitlines() if ln.strip()][:2]
            raise ValueError(
                f"{ckpt}: not this network's checkpoint ({' '.join(lines)[:200]}); delete it "
                "to train from step 0"
            ) from None
        start = int(state["iteration"])
        history = [list(map(float, row)) for row in state["history"].tolist()]
        log(f"resuming {out} at step {start} of {config.iterations}")

    def checkpoint(it: int) -> None:
        from crowdsim.atomic import atomic_path, torch_save

        with atomic_path(ckpt) as tmp:
            torch_save(
                {
                    "net": net.state_dict(),
                    "opt": opt.state_dict(),
                    "iteration": it,
                    "history": torch.tensor(history, dtype=torch.float64).reshape(-1, 4),
                },
                tmp,
                ckpt,
            )
        with recorded(out / "loss.png"):
            plot_losses(history, out / "loss.png")

    net.train()
    t1 = time.perf_counter()
    bar = progress_bar(total=config.iterations, desc="training", unit="step", enabled=progress)
    bar.update(start)
    try:
        for it in range(start, config.iterations):
            rng = np.random.default_rng([config.seed, 7, it])
            x, heat, cells, offs = make_batch(samples, rng, config.batch, config.crop)
            for g in opt.param_groups:
                g["lr"] = _lr(config, it)
            xt = torch.from_numpy(x).contiguous(memory_format=torch.channels_last)
            loss, focal, off = _loss(torch, net(xt), torch.from_numpy(heat), cells, offs)
            opt.zero_grad(set_to_none=True)
            loss.backward()
            opt.step()
            history.append([it, float(loss.detach()), focal, off])
            bar.update(1)
            if it % 20 == 0:
                bar.set_postfix(loss=f"{np.mean([h[1] for h in history[-50:]]):.3f}", refresh=False)
            if (it + 1) % config.checkpoint_every == 0 and it + 1 < config.iterations:
                checkpoint(it + 1)
    finally:
        bar.close()
    train_s = time.perf_counter() - t1
    net.eval()
    record = {
        "command": command,
        "config": asdict(config),
        "architecture": arch.to_dict(),
        "data": {
            "sequences": {k: int(sum(1 for kk, _ in specs if kk == k)) for k in MIX},
            "frames": len(samples),
            "heads": n_heads,
            "templates_px": list(TEMPLATES),
            "kinds": __doc__.split("Three kinds:")[1].split("Held-out")[0].strip(),
            "heldout": "default/hard drawn from EVAL_SEED "
            f"{EVAL_SEED}; ucf9 at the suite's own seeds (never in training)",
        },
        "final_loss": float(np.mean([h[1] for h in history[-100:]])) if history else None,
        "data_seconds": round(data_s, 1),
        "train_seconds": round(train_s, 1),
        "torch": str(torch.__version__),
        "threads": int(torch.get_num_threads()),
    }
    with recorded(*outputs):
        save_weights(out / "head_points.pt", net, arch, record)
        write_text_atomic(out / "head_points.json", json.dumps(record, indent=1) + "\n")
        plot_losses(history, out / "loss.png")
    if ckpt.is_file():
        ckpt.unlink()  # this run made it; the weights replace it
    return record


def _config_of(meta: dict, weights: Any) -> TrainConfig:
    """The :class:`TrainConfig` that made weights with ``meta`` (the defaults without one):
    fields of another release are left out, and a config that is not a table is named."""
    raw = meta.get("config", {})
    if not isinstance(raw, dict):
        raise ValueError(f"{weights or 'the weights'}: meta.config is not a table, got {raw!r:.60}")
    known = {f.name for f in fields(TrainConfig)}
    try:
        return TrainConfig(**{k: v for k, v in raw.items() if k in known})
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{weights or 'the weights'}: meta.config: {exc}") from None


def _read_checkpoint(torch: Any, path: Path) -> dict[str, Any]:
    """The training checkpoint at ``path``, or ``ValueError`` naming it when it is damaged or
    not one of :func:`train`'s (torch raises many kinds of errors for such files)."""
    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # noqa: BLE001 -- any unpickling failure is the same answer
        from tracker.detect.inference import load_failure

        raise ValueError(
            f"{path}: not a readable checkpoint ({load_failure(exc)}); delete it to train from "
            "step 0"
        ) from None
    ok = (
        isinstance(state, dict)
        and isinstance(state.get("net"), dict)
        and isinstance(state.get("opt"), dict)
        and isinstance(state.get("iteration"), int)
        and isinstance(state.get("history"), torch.Tensor)
    )
    if not ok:
        raise ValueError(
            f"{path}: not a checkpoint of crowdsim detector train (it holds net, opt, an "
            "integer iteration and a history tensor); delete it to train from step 0"
        )
    return state


def plot_losses(history: Sequence[Sequence[float]], path: Path) -> None:
    """The loss curve (total, focal, offset; a 50-step running mean) as a PNG."""
    from crowdsim.plotting import new_figure, save_figure

    if not len(history):
        return
    h = np.asarray(history, dtype=np.float64)
    k = max(1, min(50, len(h) // 5))  # a short run keeps a curve, not one averaged point
    kernel = np.ones(k) / k
    fig, ax = new_figure(figsize=(6, 3.6))
    for col, label in ((1, "total"), (2, "focal (heat map)"), (3, "offset (L1)")):
        smooth = np.convolve(h[:, col], kernel, mode="valid")
        ax.plot(h[k - 1 :, 0], smooth, label=label, lw=1.2)
    ax.set_yscale("log")
    ax.set_xlabel("step")
    ax.set_ylabel(f"loss ({k}-step mean)")
    ax.legend()
    ax.set_title("head detector training")
    save_figure(fig, path)


# ---------------------------------------------------------------------------------- evaluation
def _baseline_thresholds(
    config: TrainConfig, n_sequences: int, workers: int, progress: bool, radius: float
) -> dict[int, float]:
    """The LoG baseline's threshold per head size, fitted on the first ``n_sequences`` of the
    learnt detector's own training sequences (same data, same radius)."""
    from tracker.detect.classical import fit_threshold

    specs = training_specs(config)
    step = max(1, len(specs) // n_sequences)
    jobs = [(s, config.frames_per_sequence, k, "") for k, s in specs[::step][:n_sequences]]
    samples = render_samples(jobs, workers=workers, progress=progress, desc="baseline fit data")
    out = {}
    for size in sorted({s.template_px for s in samples}):
        mine = [s for s in samples if s.template_px == size]
        out[size] = fit_threshold(
            [s.frame for s in mine], [s.points for s in mine], size, radius, polarity="both"
        )
    return out


def _score_row(score: Any) -> dict[str, float]:
    return {
        "precision": round(score.precision, 4),
        "recall": round(score.recall, 4),
        "f1": round(score.f1, 4),
        "mean_error_px": round(score.mean_error_px, 3),
        "tp": int(score.tp),
        "fp": int(score.fp),
        "fn": int(score.fn),
    }


def evaluate(
    *,
    weights: str | None = None,
    threshold: float | None = None,
    per_kind: int = 9,
    frames: int = 3,
    radius: float = 5.0,
    baseline_sequences: int = 60,
    workers: int = 1,
    progress: bool = True,
) -> dict[str, Any]:
    """Score the learnt detector and the LoG baseline on the held-out sequences.

    Returns ``{"detector": {...}, "baseline": {...}, "rows": [...], "kinds": {...}}``: one row
    per (kind, group) with both methods' precision, recall, F1 and mean error at ``radius``
    px, and the pooled figures per kind (counts summed over frames before the ratios).
    """
    from tracker.detect.classical import LogDetector, LogParams
    from tracker.detect.inference import DetectorParams, HeadDetector
    from tracker.detect.matching import DetectionScore, score_frame

    require_number("", "--per-kind", per_kind, lo=1, hi=1000, integer=True)
    require_number("", "--frames", frames, lo=1, hi=20, integer=True)
    require_number("", "--radius", radius, lo=0, hi=1000, lo_open=True)
    require_number("", "--baseline-sequences", baseline_sequences, lo=1, hi=10_000, integer=True)
    params = DetectorParams.given(weights, threshold)
    det = HeadDetector(params)
    config = _config_of(det.meta, params.weights)
    thresholds = _baseline_thresholds(config, baseline_sequences, workers, progress, radius)
    held = heldout_specs(per_kind)
    samples = render_samples(
        [(s, frames, k, g) for k, g, s in held], workers=workers, progress=progress, desc="held-out"
    )
    from crowdsim.progress import progress_bar

    cells: dict[tuple[str, str], dict[str, Any]] = {}
    t_net = t_log = 0.0
    pixels = 0
    for s in progress_bar(samples, desc="detect", unit="frame", enabled=progress):
        key = (s.kind, s.group)
        c = cells.setdefault(key, {"net": DetectionScore(), "log": DetectionScore(), "frames": 0})
        t = time.perf_counter()
        pts, _ = det.detect_points(s.frame)
        t_net += time.perf_counter() - t
        size = min(thresholds, key=lambda k: abs(k - s.template_px))
        log_det = LogDetector(
            LogParams(template_px=s.template_px, threshold=thresholds[size], polarity="both")
        )
        t = time.perf_counter()
        lp, _ = log_det.detect_points(s.frame)
        t_log += time.perf_counter() - t
        pixels += s.frame.shape[0] * s.frame.shape[1]
        c["net"] += score_frame(pts, s.points, radius)
        c["log"] += score_frame(lp, s.points, radius)
        c["frames"] += 1
    rows = []
    kinds: dict[str, dict[str, Any]] = {}
    for (kind, group), c in cells.items():
        rows.append(
            {
                "kind": kind,
                "group": group,
                "frames": c["frames"],
                "detector": _score_row(c["net"]),
                "baseline": _score_row(c["log"]),
            }
        )
        k = kinds.setdefault(kind, {"net": DetectionScore(), "log": DetectionScore()})
        k["net"] += c["net"]
        k["log"] += c["log"]
    mpix = pixels / 1e6
    return {
        "weights": str(det.path),
        "threshold": det.params.threshold,
        "radius_px": radius,
        "frames": len(samples),
        "baseline": {
            "method": "scale-normalised LoG peaks (tracker.detect.classical), polarity both, "
            "true head size, threshold fitted per head size on the detector's training data",
            "thresholds": {str(k): round(v, 4) for k, v in thresholds.items()},
        },
        "ms_per_megapixel": {
            "detector": round(1000 * t_net / max(mpix, 1e-9), 2),
            "baseline": round(1000 * t_log / max(mpix, 1e-9), 2),
        },
        "kinds": {
            kind: {"detector": _score_row(v["net"]), "baseline": _score_row(v["log"])}
            for kind, v in kinds.items()
        },
        "rows": sorted(rows, key=lambda r: (KINDS.index(r["kind"]), r["group"])),
    }


def tracking_table(
    *,
    tracker: str = "bqp",
    weights: str | None = None,
    threshold: float | None = None,
    frames: int | None = None,
    every: int = 10,
    progress: bool = True,
) -> dict[str, Any]:
    """:func:`track_from_detections` on every held-out ``ucf9`` sequence (the suite at its
    own seeds; its first ``frames`` frames, or all), with the detector at ``threshold``, and
    the mean acc@15 of both starts and their gap."""
    from crowdsim.progress import progress_bar
    from synth_data.suites import suite_specs

    rows = [
        track_from_detections(
            spec, tracker=tracker, weights=weights, threshold=threshold, every=every, frames=frames
        )
        for spec in progress_bar(suite_specs("ucf9"), desc="tracking", unit="seq", enabled=progress)
    ]
    mean = {
        name: round(float(np.mean([r[name]["acc@15"] for r in rows])), 2)
        for name in ("ground truth", "detections")
    }
    return {
        "tracker": tracker,
        "every": every,
        "frames": frames,
        "rows": rows,
        "mean_acc15": mean,
        "gap_acc15": round(mean["ground truth"] - mean["detections"], 2),
    }


def tracking_markdown(tab: dict[str, Any]) -> str:
    lines = [
        f"## {tab['tracker']} started from the detector vs from the ground truth (ucf9, own seeds)",
        "",
        "acc@15 over the people matched within 5 px at frame 1; detector births every "
        f"{tab['every']} frames"
        + (f"; the first {tab['frames']} frames of each sequence" if tab.get("frames") else ""),
        "",
        "| sequence | people | detected | matched | born | from truth | from detector | gap |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in tab["rows"]:
        lines.append(
            f"| {r['sequence']} | {r['people_frame1']} | {r['detected_frame1']} | "
            f"{r['matched_frame1']} | {r['born_by_detector']} | "
            f"{r['ground truth']['acc@15']:.1f} | {r['detections']['acc@15']:.1f} | "
            f"{r['gap_acc15']:+.1f} |"
        )
    m = tab["mean_acc15"]
    lines.append(
        f"| **mean** | | | | | {m['ground truth']:.1f} | {m['detections']:.1f} | "
        f"{tab['gap_acc15']:+.1f} |"
    )
    return "\n".join(lines) + "\n"


def eval_markdown(rep: dict[str, Any]) -> str:
    """The evaluation as a Markdown table (pooled per kind first, then per group)."""
    r = rep["radius_px"]
    lines = [
        f"# Head detector on held-out sequences (match radius {r:g} px)",
        "",
        f"weights `{rep['weights']}`, threshold {rep['threshold']:g}; baseline: "
        f"{rep['baseline']['method']}",
        "",
        "| kind | group | frames | P | R | F1 | err px | LoG P | LoG R | LoG F1 | LoG err px |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]

    def cells(d: dict[str, float]) -> str:
        return (
            f"{d['precision']:.3f} | {d['recall']:.3f} | {d['f1']:.3f} | {d['mean_error_px']:.2f}"
        )

    for kind, v in rep["kinds"].items():
        n = sum(x["frames"] for x in rep["rows"] if x["kind"] == kind)
        lines.append(
            f"| **{kind}** | all | {n} | {cells(v['detector'])} | {cells(v['baseline'])} |"
        )
    for x in rep["rows"]:
        lines.append(
            f"| {x['kind']} | {x['group']} | {x['frames']} | {cells(x['detector'])} | "
            f"{cells(x['baseline'])} |"
        )
    ms = rep["ms_per_megapixel"]
    lines += [
        "",
        f"cost: detector {ms['detector']:.1f} ms per megapixel, LoG {ms['baseline']:.1f} "
        "(1280x720 is 0.92 megapixel)",
    ]
    if "tracking" in rep:
        lines += ["", tracking_markdown(rep["tracking"]).rstrip("\n")]
    return "\n".join(lines) + "\n"


EVAL_RECORD = "detector_eval.json"
_EVAL_WRITER = "crowdsim detector eval"


def _eval_ours(doc: dict[str, Any]) -> bool:
    """An evaluation this program wrote (evaluations before the ``written_by`` mark vouch
    by their own keys)."""
    legacy = {"weights", "threshold", "radius_px", "frames", "baseline", "kinds"} <= set(doc)
    return doc.get("written_by") == _EVAL_WRITER or legacy


def check_eval_out(out: str | os.PathLike[str]) -> None:
    """Before any work: refuse an ``--out`` that cannot be a folder written here, or that
    holds a ``detector_eval.json`` / ``.md`` this program did not write
    (:func:`envs.outputs.check_outputs`)."""
    from envs.outputs import check_outputs

    check_outputs(out, EVAL_RECORD, ("detector_eval.md",), _eval_ours, _EVAL_WRITER)


def write_eval(out: str | os.PathLike[str], rep: dict[str, Any]) -> str:
    """Write ``detector_eval.json`` (the report, which also lists the files' digests) and
    ``detector_eval.md`` into folder ``out`` (call :func:`check_eval_out` first, before any
    work); returns the Markdown."""
    from envs.outputs import write_outputs

    md = eval_markdown(rep)
    doc = {**rep, "written_by": _EVAL_WRITER}
    write_outputs(out, EVAL_RECORD, doc, {"detector_eval.md": lambda p: p.write_text(md)})
    return md


# ---------------------------------------------------------------------------------- tracking
def relabel_to_truth(
    points: np.ndarray, gt_ids: np.ndarray, gt_points: np.ndarray, radius: float = 5.0
) -> tuple[np.ndarray, np.ndarray]:
    """Ids for heads detected in the first frame: the ground-truth id of the person each is
    matched to one-to-one within ``radius`` px, fresh ids above every ground-truth id for the
    rest. Returns ``(ids (m,), matched gt ids (k,))``."""
    from tracker.detect.matching import match_points

    pts = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    gt_ids = np.asarray(gt_ids, dtype=np.int64)
    pi, gi, _ = match_points(pts, gt_points, radius)
    top = int(gt_ids.max()) + 1 if len(gt_ids) else 1
    ids = np.arange(top, top + len(pts), dtype=np.int64)
    ids[pi] = gt_ids[gi]
    return ids, np.sort(gt_ids[gi])


def track_from_detections(
    spec: Any,
    *,
    tracker: str = "bqp",
    weights: str | None = None,
    threshold: float | None = None,
    every: int = 10,
    frames: int | None = None,
    radius: float = 5.0,
) -> dict[str, Any]:
    """Track one sequence twice, from the ground truth and from the detector alone.

    The ground-truth run starts from every person at frame 1 and adds each later one at the
    frame they enter (the papers' protocol). The detection run starts from the heads the
    detector finds in frame 1 and adds the heads it finds every ``every`` frames that no
    track covers (:class:`synth_data.births.DetectionBirths`, radius: the head size). Both are
    scored by acc@5 and acc@15 over the ground-truth people *matched* at frame 1 (a detected
    head within ``radius`` px, one-to-one), the figure that compares the two starts.
    """
    from synth_data.births import DetectionBirths
    from synth_data.sequence import InMemorySequence
    from tracker.detect.inference import DetectorParams, HeadDetector
    from tracker.metrics import accuracy_curve
    from tracker.runner import run_tracker

    params = DetectorParams.given(weights, threshold)
    seq = InMemorySequence.from_spec(spec, frames=frames, camera_output=True).materialize()
    det = HeadDetector(params, template_size=seq.template_size)
    gt_ids, gt_pts = seq.gt_points()
    first = next(iter(seq.frames()))
    found, _ = det.detect_points(first)
    ids0, matched = relabel_to_truth(found, gt_ids, gt_pts[0], radius)
    present0 = int(np.isfinite(gt_pts[0]).all(1).sum())
    (_, _), scheduled = seq.births()
    births = DetectionBirths(
        det.detect_points,
        every=every,
        radius=float(seq.template_size),
        first_id=int(max(ids0.max(initial=0), gt_ids.max(initial=0))) + 1,
    )
    runs = {
        "ground truth": run_tracker(tracker, seq, metrics="none"),
        "detections": run_tracker(
            tracker, seq, metrics="none", start=((ids0, found), {}), births=births
        ),
    }
    cols = np.isin(gt_ids, matched)
    out: dict[str, Any] = {
        "sequence": spec.name,
        "people_frame1": present0,
        "detected_frame1": len(found),
        "matched_frame1": len(matched),
        "born_by_detector": births.born,
        "frames": int(seq.length),
    }
    for name, run in runs.items():
        res = run.result
        curve = accuracy_curve(
            gt_ids[cols], gt_pts[: res.n_frames][:, cols], res.ids, res.positions
        )
        out[name] = {"acc@5": round(float(curve[5]), 2), "acc@15": round(float(curve[15]), 2)}
    out["gap_acc15"] = round(out["ground truth"]["acc@15"] - out["detections"]["acc@15"], 2)
    return out
