"""How sharp the renderer draws the ground under camera shake, against its still twin.

For each shaken sequence of a suite (default ``ucf9-shake``) this draws the ground alone (no
people, no sensor noise, no illumination drift) for ``--frames`` frames twice on the same
canvas: with the spec's shake, and held still (no jitter and no shake bursts, with the
shaken camera's ``ground_margin_px``, as ``crowdsim difficulty``'s ``-shake`` variant draws
its ground). It reports the mean
variance of each grey frame's Laplacian, the energy of the finest texture, and the ratio
shaken / still. A shaken frame samples the ground between pixels (bilinearly), which softens
it: a ratio under 1 is texture that a still camera shows and a shaken one does not::

    python benchmarks/ground_sharpness.py --only seq4 seq6 seq7

Prints a table and one JSON object.
"""

from __future__ import annotations

import argparse
import json
from dataclasses import replace

import numpy as np

from crowdsim.bench import add_suite_arguments, suite_specs_or_exit


def measure(spec, frames: int) -> dict:
    """Mean Laplacian variance of the ground alone, shaken and still, over ``frames`` frames."""
    import cv2

    from crowdsim.render import SceneRenderer
    from synth_data.scene import Scene

    cam = Scene.from_spec(spec.truncated(2)).camera
    params = replace(spec.appearance, noise_sigma=0.0, illumination_drift=0.0)
    still = replace(cam, jitter_px=0.0, shake_events=(), ground_margin_px=cam.ground_margin)
    nobody = (np.zeros((0, 2)), np.zeros(0), np.zeros(0, np.int64))
    row = {"shake_px": cam.shake_px}
    for label, camera in (("shaken", cam), ("still", still)):
        renderer = SceneRenderer(camera, params, seed=spec.seed, fps=spec.fps)
        energy = []
        for t in range(frames):
            grey = cv2.cvtColor(renderer.render(t, *nobody), cv2.COLOR_BGR2GRAY)
            energy.append(float(cv2.Laplacian(grey.astype(np.float32), cv2.CV_32F).var()))
        row[label] = float(np.mean(energy))
    row["ratio"] = row["shaken"] / row["still"]
    return row


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    add_suite_arguments(ap, "ucf9-shake")
    ap.add_argument("--frames", type=int, default=40, help="frames per sequence, 1..10000 (40)")
    args = ap.parse_args()
    if not 1 <= args.frames <= 10_000:
        ap.error(f"--frames must be in [1, 10000], got {args.frames}")
    specs = suite_specs_or_exit(ap, args)
    print(f"{'sequence':<10}{'shake px':>10}{'shaken':>10}{'still':>10}{'ratio':>8}")
    rows = {}
    for spec in specs:
        if not float(spec.camera.get("jitter_px", 0.0)) > 0:
            continue  # nothing shakes: nothing to compare
        r = rows[spec.name] = measure(spec, args.frames)
        print(
            f"{spec.name:<10}{r['shake_px']:>10.2f}{r['shaken']:>10.1f}{r['still']:>10.1f}"
            f"{r['ratio']:>8.2f}",
            flush=True,
        )
    print(json.dumps({"suite": args.suite, "frames": args.frames, "sequences": rows}))
    return 0


if __name__ == "__main__":
    from crowdsim.bench import run_script

    raise SystemExit(run_script(main, "ground_sharpness.py"))
