"""How much of what shake costs a tracker could any camera-motion estimate regain?

For each sequence of a suite (default ``ucf9-shake``) this tracks, with the tracker (default
BQP with KCF appearance), four renderings of the same scene through the camera output (codec
and JPEG, what a tracker reads):

* ``shaken``: the spec as it is;
* ``+cmc``: the same frames with camera-motion compensation (``cmc=True``, the estimate of
  :class:`tracker.cmc.MotionCompensator`);
* ``+planted``: the same frames compensated by the shake the camera planted
  (``Camera.jitter``: the exact translation of every frame, what a perfect estimate gives);
* ``still``: the still twin of ``crowdsim difficulty``'s ``-shake`` column (the shake group
  at its uncalibrated value, the same ground: :func:`crowdsim.lab.difficulty.variant_specs`).

``still - shaken`` is what shake costs; ``+cmc`` and ``+planted`` are what the estimate and a
perfect one regain of it. Where even the planted shake regains little, the cost is not the
estimate's error but what the shaken frames hold besides the motion, or the run's noise.
``--jiggle SIGMA --seeds N`` measures that noise: the planted shake plus seeded Gaussian
errors of ``SIGMA`` px per axis and frame (an estimate about as good as the default's), once
per seed; the spread of these runs is how much one sequence's figure moves when the
compensation moves by a fraction of a pixel::

    python benchmarks/cmc_oracle.py --only seq4 seq6
    python benchmarks/cmc_oracle.py --only seq6 --jiggle 0.3 --seeds 4

``--raw`` tracks the frames as drawn instead, before the codec and JPEG: where shake costs
points through the compression (a moving view leaves the encoder fewer bits for the people),
it costs fewer there, and compensation cannot regain them.

Prints a table (acc@15 %, points) and one JSON object.
"""

from __future__ import annotations

import argparse
import json
from functools import partial

import numpy as np

from crowdsim.bench import add_suite_arguments, cmc_tracker_or_exit, suite_specs_or_exit


def planted_compensator(motion: np.ndarray, base_cls, error: np.ndarray | None = None):
    """A :class:`tracker.cmc.MotionCompensator` whose estimate into frame ``t`` is the
    camera's planted map ``motion[t - 1]`` (:meth:`crowdsim.camera.Camera.frame_motion`; the
    identity into the first frame), its shift plus ``error[t]`` if given (``(n_frames, 2)``;
    row 0, the first frame's, unused)."""
    from tracker.cmc import IDENTITY

    maps = np.array(motion, dtype=np.float64)
    if error is not None:
        maps[:, :, 2] += error[1 : len(maps) + 1]

    class Planted(base_cls):
        def estimate(self, frame, exclude=None, exclude_px=0.0):
            t = self.frames
            self.frames += 1
            a = maps[t - 1].copy() if 0 < t <= len(maps) else IDENTITY.copy()
            self.last = a
            return a

    return Planted


def planted_prepare(motion: np.ndarray, error: np.ndarray | None = None):
    """``run_tracker``'s ``prepare`` that gives the tracker :func:`planted_compensator`'s
    estimate in place of its own whenever it starts compensating."""
    from tracker.cmc import MotionCompensator

    planted = planted_compensator(motion, MotionCompensator, error)

    def prepare(trk, _source):
        start = trk._start_compensator

        def start_planted():
            start()
            if trk.compensator is not None:
                trk.compensator = planted(trk.compensator.params)
                if trk._last_frame is not None:  # shown the last frame, as start() does
                    trk.compensator.estimate(trk._last_frame)

        trk._start_compensator = start_planted

    return prepare


def measure(spec, tracker: str, jiggle: float = 0.0, seeds: int = 0, raw: bool = False) -> dict:
    """acc@15 of ``tracker`` on ``spec`` shaken, compensated, compensated by the planted
    shake, and on its still twin; with ``seeds``, also compensated by the planted shake plus
    ``jiggle`` px of seeded error, once per seed (``+jiggled``)."""
    from crowdsim.lab.difficulty import variant_specs
    from synth_data.scene import Scene
    from synth_data.sequence import InMemorySequence
    from synth_data.video import camera_output
    from tracker.runner import run_tracker

    def render(s):  # one simulation gives the frames and the camera that moved them
        scene = Scene.from_spec(s)
        out = None if raw else partial(camera_output, fps=s.fps, encoding=s.appearance.encoding)
        return scene, InMemorySequence.from_scene(scene, output=out).materialize()

    scene, seq = render(spec)
    motion = scene.camera.frame_motion(seq.length)

    def plant(error=None):
        return planted_prepare(motion, error)

    def acc(source, cmc: bool, prepare=None) -> float:
        run = run_tracker(tracker, source, params={"cmc": cmc}, metrics="accuracy", prepare=prepare)
        return float(run.report["acc@15"])

    row = {
        "shaken": acc(seq, False),
        "+cmc": acc(seq, True),
        "+planted": acc(seq, True, plant()),
    }
    if seeds:
        shape = (len(motion) + 1, 2)  # a row per frame, as the jitter
        row["+jiggled"] = [
            acc(seq, True, plant(np.random.default_rng(s).normal(0.0, jiggle, shape)))
            for s in range(seeds)
        ]
    _, still = render(dict(variant_specs(spec, ["shake"]))["-shake"])
    row["still"] = acc(still, False)
    row["shake_px"] = float(np.abs(motion[:, :, 2]).mean())
    cost = row["still"] - row["shaken"]
    row["cost"] = cost
    for name in ("+cmc", "+planted"):
        gain = row[name] - row["shaken"]
        row[f"{name} share"] = gain / cost if cost > 0 else None
    return row


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    add_suite_arguments(ap, "ucf9-shake")
    ap.add_argument("--tracker", default="bqp", help="a registered detection-free tracker")
    ap.add_argument(
        "--jiggle",
        type=float,
        default=0.3,
        metavar="SIGMA",
        help="px of seeded error per axis and frame added to the planted shake",
    )
    ap.add_argument("--seeds", type=int, default=0, help="runs with --jiggle, one per seed")
    ap.add_argument("--raw", action="store_true", help="the frames as drawn: no codec, no JPEG")
    args = ap.parse_args()
    if not (args.jiggle >= 0 and args.seeds >= 0):
        ap.error(f"--jiggle and --seeds must be >= 0, got {args.jiggle} and {args.seeds}")
    cmc_tracker_or_exit(ap, args.tracker)
    specs = [s for s in suite_specs_or_exit(ap, args) if s.calibration]
    if not specs:
        ap.error(f"suite {args.suite!r}: no calibrated sequence")
    cols = ("shaken", "still", "cost", "+cmc", "+planted", "+cmc share", "+planted share")
    print(f"{'sequence':<10}" + "".join(f"{c:>15}" for c in cols) + "   (acc@15 %, points)")
    rows = {}
    for spec in specs:
        r = rows[spec.name] = measure(spec, args.tracker, args.jiggle, args.seeds, args.raw)
        cells = [
            f"{r['shaken']:.1f}",
            f"{r['still']:.1f}",
            f"{r['cost']:+.1f}",
            f"{r['+cmc'] - r['shaken']:+.1f}",
            f"{r['+planted'] - r['shaken']:+.1f}",
        ]
        cells += ["" if r[f"{n} share"] is None else f"{100 * r[f'{n} share']:.0f} %"
                  for n in ("+cmc", "+planted")]  # fmt: skip
        print(f"{spec.name:<10}" + "".join(f"{c:>15}" for c in cells), flush=True)
        if args.seeds:
            gains = np.array(r["+jiggled"]) - r["shaken"]
            print(f"{'':<10}planted + {args.jiggle:g} px of error, {args.seeds} seeds: "
                  f"{' '.join(f'{g:+.1f}' for g in gains)} points (spread {np.ptp(gains):.1f})",
                  flush=True)  # fmt: skip
    doc = {"suite": args.suite, "tracker": args.tracker, "raw": args.raw, "sequences": rows}
    print(json.dumps(doc))
    return 0


if __name__ == "__main__":
    from crowdsim.bench import run_script

    raise SystemExit(run_script(main, "cmc_oracle.py"))
