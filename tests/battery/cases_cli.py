"""Bad command lines of simulate, render, evaluate, track, generate and demo (issue 10)."""

from __future__ import annotations

import os
import shutil
from collections.abc import Callable
from pathlib import Path

import numpy as np

from battery.harness import (
    GOOD_CSV,
    SPEC,
    Env,
    _append_gt,
    _gt,
    _ini,
    _truncate_jpeg,
    case,
    seq_copy,
)

# --- simulate ---------------------------------------------------------------------------
SIM = "simulate marathon --agents 4 --steps 2 --no-progress"
case("sim-agents-0", f"{SIM} --agents 0", "--agents must be in [1, 1000000], got 0")
case("sim-agents-huge", f"{SIM} --agents 10000000", "got 10000000")
case("sim-agents-text", f"{SIM} --agents many", "'many'")
case("sim-steps-neg", f"{SIM} --steps -1", "--steps must be >= 0, got -1")
case(
    "sim-steps-memory",
    f"{SIM} --steps 100000000 --agents 100000",
    "--steps 100000000 x --agents 100000 needs about",
)
case(
    "sim-steps-inflow-memory",  # 50 people at the start, but the station's doors bring more
    "simulate station --agents 50 --steps 100000 --no-progress",
    "--steps 100000 with the scenario's inflow (about 17,574 more people at 4.39 a second",
)
case("sim-steps-float", f"{SIM} --steps 2.5", "'2.5'")
case(  # a finite but absurd force overflows the state: one line, not FloatingPointError's trace
    "sim-param-overflow",
    "simulate counterflow --agents 20 --steps 30 --no-progress --param U0=1e308",
    "or the force strengths (--param); nothing written",
)
case("sim-dt-0", f"{SIM} --dt 0", "--dt must be in (0, 0.2] seconds, got 0.0")
# sizes and speeds far outside any crowd: named before the world's walls fill the memory
SIM1 = "simulate {} --agents 10 --steps 1 --no-progress --set {}"
case(
    "sim-width-huge",
    SIM1.format("counterflow", "width=1e9"),
    "counterflow.width must be a finite number in (0, 10000], got 1000000000.0",
)
case("sim-width-1e308", SIM1.format("groups", "width=1e308"), "groups.width must be a finite")
case("sim-door-huge", SIM1.format("station", "door_width=1e9"), "station.door_width must be a")
case(
    "sim-pillars-tight",
    SIM1.format("station", "pillar_spacing=0.01"),
    "station.pillar_spacing must be 0 (no pillars) or >= 1.4 m",
)
case(  # the hall held 924 of the 1,000 people asked for, and the run went on with them
    "sim-station-too-dense",
    "simulate station --agents 1000 --density 1.5 --steps 1 --no-progress",
    "station.density 1.5 /m² is too high for n_agents 1000: only 924 people fit",
)
case(  # the list given is a list, an empty one: "must be a list, got ()" misled
    "sim-kinds-empty",
    SIM1.format("anomalies", "kinds=[]"),
    "anomalies.kinds must be a non-empty list, got []",
)
case(
    "sim-speed-huge",
    SIM1.format("circulation", "speed_mean=1e9"),
    "circulation.speed_mean must be a finite number in (0, 10], got 1000000000.0",
)
case(  # pymunk's iterations are a C int: OverflowError's traceback from the first step
    "sim-param-iterations-huge",
    f"{SIM} --param solver_iterations=3000000000",
    "SocialForceParams.solver_iterations must be an integer in [1, 10000], got 3000000000",
)
case(  # 1e20 pymunk sub-steps a step: the run never ended
    "sim-param-substeps-huge",
    f"{SIM} --param contact_substeps=1e20",
    "SocialForceParams.contact_substeps must be an integer in [1, 10000], got 1e+20",
)
case("sim-dt-neg", f"{SIM} --dt -0.04", "got -0.04")
case("sim-dt-nan", f"{SIM} --dt nan", "got nan")
case("sim-dt-inf", f"{SIM} --dt inf", "got inf")
case("sim-dt-big", f"{SIM} --dt 5", "got 5.0")
case("sim-density-0", f"{SIM} --density 0", "--density must be in (0, 6]")
case("sim-density-big", f"{SIM} --density 7", "got 7.0")
case("sim-density-nan", f"{SIM} --density nan", "got nan")
case("sim-seed-neg", f"{SIM} --seed -3", "--seed must be in [0, 2**63), got -3")
case("sim-seed-huge", f"{SIM} --seed 99999999999999999999999", "got 99999999999999999999999")
case("sim-scenario-unknown", "simulate nosuch --steps 1", "nosuch")
case("sim-out-suffix", f"{SIM} --out {{w}}/t.txt", "--out must end in .npz")
case("sim-plot-suffix", f"{SIM} --plot {{w}}/t.jpg", "--plot must end in .png")
case("sim-out-under-file", f"{SIM} --out {{afile}}/t.npz", "afile is a file, not a folder")
case("sim-out-deep-under-file", f"{SIM} --out {{afile}}/a/b/t.npz", "afile is a file, not a folder")
case(
    "sim-out-is-folder",
    f"{SIM} --out {{w}}/d.npz",
    "d.npz: is a folder, not a file",
    setup=lambda w, env: (w / "d.npz").mkdir(),
)
case("sim-plot-under-file", f"{SIM} --plot {{afile}}/t.png", "afile is a file, not a folder")
case(
    "sim-plot-is-folder",
    f"{SIM} --plot {{w}}/p.png",
    "p.png: is a folder, not a file",
    setup=lambda w, env: (w / "p.png").mkdir(),
)
case(
    "sim-out-sysfs",
    f"{SIM} --out /sys/crowdsim-battery.npz",
    "/sys/crowdsim-battery.npz: permission denied",
)
case("sim-out-readonly", f"{SIM} --out {{ro}}/t.npz", "is not writable", needs="ro")
case(
    "sim-out-full-disk",
    f"{SIM} --agents 100 --steps 10 --out {{full}}/t.npz",
    "{full}/t.npz: no space left on the device",
    needs="full",
)
case("sim-set-no-equals", f"{SIM} --set width", "--set expects NAME=VALUE, got 'width'")
case("sim-set-unknown", f"{SIM} --set nosuchparam=3", "nosuchparam")
case("sim-set-agents", f"{SIM} --set n_agents=5", "--set n_agents: use --agents instead")
case("sim-set-density", f"{SIM} --set density=2", "--set density: use --density instead")
case("sim-set-bad-yaml", f"{SIM} --set width=[1,", "cannot parse value '[1,'")
case("sim-set-width-neg", f"{SIM} --set road_width=-3", "road_width&&-3")
case("sim-set-width-inf", f"{SIM} --set road_width=inf", "road_width&&inf")
case("sim-set-width-nan", f"{SIM} --set road_width=nan", "road_width&&nan")
case("sim-set-width-text", f"{SIM} --set road_width=wide", "road_width&&wide")
case("sim-set-unknown-for-scenario", f"{SIM} --set width=3", "width&&known:")
case("sim-param-unknown", f"{SIM} --param nosuch=1", "nosuch")
case("sim-param-dt", f"{SIM} --param dt=0.1", "--param dt: use --dt instead")
case("sim-param-tau-neg", f"{SIM} --param tau=-1", "tau")
case("sim-param-tau-nan", f"{SIM} --param tau=nan", "nan")
case("sim-param-tau-text", f"{SIM} --param tau=fast", "fast")
case("sim-param-tau-inf", f"{SIM} --param tau=inf", "inf")
case("sim-param-empty-name", f"{SIM} --param =3", "--param expects NAME=VALUE, got '=3'")
case("sim-param-mass-0", f"{SIM} --param mass=0", "mass")

# --- render -----------------------------------------------------------------------------
R = "render --fps 10 --out {w}/seq"
RCSV = "render --trajectories {w}/t.csv --fps 10 --out {w}/seq"


def csv_case(id: str, content: str, needle: str, flags: str = "", **kw) -> None:
    case(id, f"{RCSV} {flags}".strip(), needle, files=(("t.csv", content),), **kw)


HDR = "frame,id,x,y\n"
case(
    "render-no-traj-file",
    f"{R} --trajectories {{w}}/missing.csv",
    "missing.csv: no such trajectory file",
)
case(
    "render-traj-is-folder",
    f"{R} --trajectories {{w}}/d.csv",
    "d.csv: is a folder",
    setup=lambda w, env: (w / "d.csv").mkdir(),
)
case(
    "render-traj-suffix",
    f"{R} --trajectories {{w}}/t.txt",
    "--trajectories must be a .csv or .npz file",
    files=(("t.txt", GOOD_CSV),),
)
case("render-csv-no-fps", "render --trajectories {csv} --out {w}/seq", "--fps is required for CSV")
case("render-fps-0", "render --trajectories {csv} --fps 0 --out {w}/seq", "got 0.0")
case("render-fps-neg", "render --trajectories {csv} --fps -5 --out {w}/seq", "got -5.0")
case("render-fps-nan", "render --trajectories {csv} --fps nan --out {w}/seq", "got nan")
case("render-fps-inf", "render --trajectories {csv} --fps inf --out {w}/seq", "got inf")
case(
    "render-fps-huge",
    "render --trajectories {csv} --fps 1e9 --out {w}/seq",
    "--fps must be in (0, 1000], got 1000000000.0",
)
case(
    "render-ppm-0",
    "render --trajectories {csv} --fps 10 --px-per-m 0 --out {w}/seq",
    "--px-per-m must be in [0.001, 10000], got 0",
)
case("render-ppm-neg", "render --trajectories {csv} --fps 10 --px-per-m -3 --out {w}/seq", "got -3")
case(
    "render-ppm-nan", "render --trajectories {csv} --fps 10 --px-per-m nan --out {w}/seq", "got nan"
)
case(
    "render-ppm-1e9",
    "render --trajectories {csv} --fps 10 --px-per-m 1e9 --out {w}/seq",
    "--px-per-m must be in [0.001, 10000], got 1e+09",
)
case(
    "render-ppm-empties-gt",
    "render --trajectories {w}/t.csv --fps 10 --px-per-m 5000 --out {w}/seq",
    "--px-per-m 5000: no trajectory point falls inside",
    files=(("t.csv", HDR + "0,1,0,0\n0,2,10,10\n1,1,0.1,0\n1,2,10.1,10\n"),),
)
case("render-period-0", "render --trajectories {csv} --fps 10 --period 0 --out {w}/seq", "got 0")
case(
    "render-period-nan",
    "render --trajectories {csv} --fps 10 --period nan --out {w}/seq",
    "--period must be a length > 0 m, got nan",
)
case(
    "render-period-short",
    "render --trajectories {w}/t.csv --fps 10 --period 5 --out {w}/seq",
    "t.csv:3: x = 6 m lies outside the periodic axis [0, 5] m",
    files=(("t.csv", HDR + "0,1,1,1\n0,2,6,1\n"),),
)
case(
    "render-period-npz",
    "render --trajectories {npz} --period 10 --out {w}/seq",
    "--period is for CSV trajectories; a .npz from crowdsim simulate carries its own",
)
case(
    "render-size-text",
    "render --trajectories {csv} --fps 10 --size big --out {w}/seq",
    "--size must look like 1280x720, got 'big'",
)
case(
    "render-size-one", "render --trajectories {csv} --fps 10 --size 640 --out {w}/seq", "got '640'"
)
case(
    "render-size-float",
    "render --trajectories {csv} --fps 10 --size 64.5x48 --out {w}/seq",
    "got '64.5x48'",
)
case(
    "render-size-small", "render --trajectories {csv} --fps 10 --size 4x4 --out {w}/seq", "got 4x4"
)
case(
    "render-size-neg",
    "render --trajectories {csv} --fps 10 --size=-64x48 --out {w}/seq",
    "got -64x48",
)
case(
    "render-size-largest+1",
    "render --trajectories {csv} --fps 10 --size 8193x8192 --out {w}/seq",
    "got 8193x8192",
)
case(
    "render-size-huge",
    "render --trajectories {csv} --fps 10 --size 100000x100000 --out {w}/seq",
    "got 100000x100000",
)
case(
    "render-template-0",
    "render --trajectories {csv} --fps 10 --template-px 0 --out {w}/seq",
    "--template-px must be in [4, 64], got 0",
)
case(
    "render-template-5000",
    "render --trajectories {csv} --fps 10 --template-px 5000 --out {w}/seq",
    "got 5000",
)
case(
    "render-seed-neg",
    "render --trajectories {csv} --fps 10 --seed -1 --out {w}/seq",
    "--seed must be in [0, 2**63), got -1",
)
case(  # a sequence written into another one: the outer one no longer provably crowdsim's
    "render-out-in-sequence",
    "render --trajectories {csv} --fps 10 --out {seq}/gt/inner",
    "lies in a sequence folder",
)
case("render-seed-huge", "render --trajectories {csv} --fps 10 --seed 1e3 --out {w}/seq", "'1e3'")
case(
    "render-out-exists",
    "render --trajectories {csv} --fps 10 --out {w}/seq",
    "--out {w}/seq already exists; pass --overwrite",
    setup=lambda w, env: shutil.copytree(env.seq, w / "seq"),
)
case(
    "render-overwrite-user-folder",
    "render --trajectories {csv} --fps 10 --overwrite --out {w}/thesis",
    "--out {w}/thesis is not a crowdsim sequence or suite folder",
    files=(("thesis/thesis.tex", "\\chapter{One}\n"),),
)
case(
    "render-overwrite-empty-folder",
    "render --trajectories {csv} --fps 10 --overwrite --out {w}/empty",
    "is not a crowdsim sequence",
    setup=lambda w, env: (w / "empty").mkdir(),
)
case(
    "render-overwrite-seq-with-user-file",
    "render --trajectories {csv} --fps 10 --overwrite --out {w}/seq",
    "is not a crowdsim sequence",
    setup=lambda w, env: (
        shutil.copytree(env.seq, w / "seq"),
        (w / "seq" / "notes.txt").write_text("mine\n"),
    ),
)
case(
    "render-overwrite-fake-seq",
    "render --trajectories {csv} --fps 10 --overwrite --out {w}/fake",
    "is not a crowdsim sequence",
    files=(("fake/seqinfo.ini", "[Sequence]\nname=x\n"), ("fake/gt/gt.txt", "")),
)
case(
    "render-overwrite-file",
    "render --trajectories {csv} --fps 10 --overwrite --out {w}/paper.pdf",
    "--out {w}/paper.pdf is a file, not a crowdsim sequence folder",
    files=(("paper.pdf", b"%PDF-1.4\n"),),
)
case(
    "render-overwrite-input-csv",
    "render --trajectories {w}/t.csv --fps 10 --overwrite --out {w}/t.csv",
    "would replace the input",
    files=(("t.csv", GOOD_CSV),),
)
case(
    "render-overwrite-input-inside",
    "render --trajectories {w}/data/t.csv --fps 10 --overwrite --out {w}/data",
    "would replace the input",
    files=(("data/t.csv", GOOD_CSV),),
)
case(
    "render-overwrite-input-npz",
    "render --trajectories {npz} --overwrite --out {npz}",
    "would replace the input",
)
case(
    "render-overwrite-root-with-input",
    "render --trajectories {csv} --fps 10 --overwrite --out {root}",
    "would replace the input",
)
case(
    "render-overwrite-symlink",
    "render --trajectories {csv} --fps 10 --overwrite --out {w}/link",
    "is a file, not a crowdsim sequence folder",
    setup=lambda w, env: (w / "link").symlink_to(env.seq),
)
case(
    "render-out-under-file",
    "render --trajectories {csv} --fps 10 --out {afile}/seq",
    "--out {afile}/seq: {afile} is a file, not a folder",
)
case("render-out-dot", "render --trajectories {csv} --fps 10 --out .", "--out must name a folder")
case(
    "render-out-sysfs",
    "render --trajectories {csv} --fps 10 --out /sys/crowdsim-battery",
    "/sys/crowdsim-battery",
)
case(
    "render-out-readonly",
    "render --trajectories {csv} --fps 10 --out {ro}/seq",
    "--out {ro}/seq: the folder {ro} is not writable",
    needs="ro",
)
case(
    "render-out-full-disk",
    "render --trajectories {csv} --fps 10 --size 256x256 --out {full}/seq",
    "no space left on the device",
    needs="full",
)
csv_case("csv-coord-1e12", HDR + "0,1,1e12,0\n1,1,1,0\n", "x 1e12 m is outside")
csv_case("csv-coord-1e300", HDR + "0,1,0,1e300\n1,1,1,0\n", "y 1e300 m is outside")
csv_case("csv-coord-neg-big", HDR + "0,1,-200000,0\n", "x -200000 m is outside")
csv_case("csv-coord-inf", HDR + "0,1,inf,0\n", "x inf is not finite")
csv_case("csv-coord-nan", HDR + "0,1,nan,0\n", "x nan is not finite")
csv_case("csv-coord-text", HDR + "0,1,abc,0\n", "x 'abc' is not a number")
csv_case("csv-coord-empty", HDR + "0,1,,0\n", "x '' is not a number")
csv_case(
    "csv-id-int64+1",
    HDR + "0,9223372036854775808,1,1\n0,1,2,2\n",
    "id 9223372036854775808 is outside the int64 range",
)
csv_case(
    "csv-id-huge-merge",
    HDR + "0,18446744073709551617,1,1\n0,18446744073709551618,2,2\n",
    "id 18446744073709551617 is outside the int64 range",
)
csv_case("csv-id-1e19", HDR + "0,1e19,1,1\n", "id 1e19 is outside the int64 range")
csv_case("csv-id-float-big", HDR + "0,1e17,1,1\n", "id 1e17 is too large to be read exactly")
csv_case("csv-id-2.5", HDR + "0,2,1,1\n0,2.5,2,2\n", "id 2.5 is not an integer")
csv_case("csv-id-text", HDR + "0,bob,1,1\n", "id 'bob' is not a number")
csv_case("csv-id-nan", HDR + "0,nan,1,1\n", "id nan is not finite")
csv_case("csv-frame-2.5", HDR + "0,1,1,1\n2.5,1,2,2\n", "frame 2.5 is not an integer")
csv_case("csv-frame-0.1", HDR + "0.1,1,1,1\n", "frame 0.1 is not an integer")
csv_case("csv-frame-text", HDR + "first,1,1,1\n0,1,1,1\n", "the header must be frame,id,x,y")
csv_case("csv-frame-inf", HDR + "inf,1,1,1\n", "frame inf is not finite")
csv_case("csv-frame-2e9", HDR + "0,1,1,1\n2000000000,1,2,2\n", "frames 0..2000000000 x 1 ids")
csv_case(
    "csv-frame-memory-many-ids",
    HDR + "".join(f"0,{i},1,1\n" for i in range(2000)) + "400000,1,1,1\n",
    "needs about",
)
csv_case(
    "csv-frame-int64+1",
    HDR + "9223372036854775808,1,1,1\n",
    "frame 9223372036854775808 is outside the int64 range",
)
csv_case(
    "csv-frame-span-overflow",
    HDR + "-9223372036854775807,1,1,1\n9223372036854775806,1,1,1\n",
    "needs about",
)
csv_case("csv-extra-column", HDR + "0,1,1,1,7\n", "expected 4 columns frame,id,x,y, got 5")
csv_case(
    "csv-extra-header",
    "frame,id,x,y,z\n0,1,1,1,1\n",
    "the header must be frame,id,x,y, got 'frame,id,x,y,z'",
)
csv_case("csv-few-columns", HDR + "0,1,1\n", "expected 4 columns frame,id,x,y, got 3")
csv_case("csv-one-column", HDR + "0\n", "got 1")
csv_case(
    "csv-duplicate",
    HDR + "0,1,1,1\n1,1,2,2\n0,1,3,3\n",
    "frame 0, id 1 appears twice (also on line 2)",
)
csv_case("csv-duplicate-int-float", HDR + "0,1,1,1\n0.0,1.0,3,3\n", "frame 0, id 1 appears twice")
csv_case("csv-empty", "", "t.csv: no trajectory rows")
csv_case("csv-header-only", HDR, "t.csv: no trajectory rows")
csv_case("csv-comments-only", "# nothing\n", "no trajectory rows")
csv_case("csv-binary", "\x00\x01\x02", "the header must be frame,id,x,y")
case(
    "csv-undecodable",
    RCSV,
    "t.csv: not a text CSV file",
    files=(("t.csv", b"frame,id,x,y\n\xff\xfe\x00,1,1,1\n"),),
)
csv_case(
    "csv-wrong-header",
    "time,person,x,y\n0,1,1,1\n",
    "the header must be frame,id,x,y, got 'time,person,x,y'",
)


def _npz(name: str, **arrays) -> Callable[[Path, Env], None]:
    def setup(w: Path, env: Env) -> None:
        np.savez(w / name, **arrays)

    return setup


RNPZ = "render --trajectories {w}/t.npz --out {w}/seq"
case(
    "npz-text-file",
    RNPZ,
    "t.npz: not a crowdsim trajectories .npz (not a zip archive",
    files=(("t.npz", "frame,id,x,y\n0,1,1,1\n"),),
)
case("npz-empty-file", RNPZ, "t.npz: not a crowdsim trajectories .npz", files=(("t.npz", ""),))
case(
    "npz-truncated-zip",
    RNPZ,
    "t.npz: not a crowdsim trajectories .npz",
    setup=lambda w, env: (w / "t.npz").write_bytes(env.npz.read_bytes()[:60]),
)
case(
    "npz-missing-positions",
    RNPZ,
    "missing array 'positions'",
    setup=_npz("t.npz", ids=np.arange(2), dt=np.float64(0.1)),
)
case(
    "npz-missing-dt",
    RNPZ,
    "missing array 'dt'",
    setup=_npz("t.npz", positions=np.zeros((2, 2, 2)), ids=np.arange(2)),
)
case(
    "npz-positions-2d",
    RNPZ,
    "positions must have shape (T, N, 2), got (2, 2)",
    setup=_npz("t.npz", positions=np.zeros((2, 2)), ids=np.arange(2), dt=np.float64(0.1)),
)
case(
    "npz-positions-inf",
    RNPZ,
    "x = inf m at row 0, column 0",
    setup=_npz(
        "t.npz", positions=np.array([[[np.inf, 0.0]]]), ids=np.arange(1), dt=np.float64(0.1)
    ),
)
case(
    "npz-positions-1e12",
    RNPZ,
    "y = 1e+12 m at row 0, column 0",
    setup=_npz("t.npz", positions=np.array([[[0.0, 1e12]]]), ids=np.arange(1), dt=np.float64(0.1)),
)
case(
    "npz-ids-float",
    RNPZ,
    "ids must be integers, got dtype float64",
    setup=_npz(
        "t.npz", positions=np.zeros((1, 2, 2)), ids=np.array([1.0, 2.5]), dt=np.float64(0.1)
    ),
)
case(
    "npz-ids-duplicate",
    RNPZ,
    "id 3 appears 2 times",
    setup=_npz("t.npz", positions=np.zeros((1, 2, 2)), ids=np.array([3, 3]), dt=np.float64(0.1)),
)
case(
    "npz-ids-shape",
    RNPZ,
    "ids must have shape (2,), got (3,)",
    setup=_npz("t.npz", positions=np.zeros((1, 2, 2)), ids=np.arange(3), dt=np.float64(0.1)),
)
case(
    "npz-dt-0",
    RNPZ,
    "dt must be a positive number of seconds, got 0.0",
    setup=_npz("t.npz", positions=np.zeros((1, 1, 2)), ids=np.arange(1), dt=np.float64(0)),
)
case(
    "npz-dt-array",
    RNPZ,
    "dt must be one number of seconds",
    setup=_npz("t.npz", positions=np.zeros((1, 1, 2)), ids=np.arange(1), dt=np.array([0.1, 0.2])),
)
case(
    "npz-pickled",
    RNPZ,
    "t.npz: not a crowdsim trajectories .npz",
    setup=lambda w, env: np.savez(
        w / "t.npz",
        positions=np.array([{"a": 1}], dtype=object),
        ids=np.arange(1),
        dt=np.float64(0.1),
    ),
)
case(
    "npz-all-nan",
    RNPZ,
    "the trajectories contain no present position",
    setup=_npz("t.npz", positions=np.full((2, 1, 2), np.nan), ids=np.arange(1), dt=np.float64(0.1)),
)
case(
    "npz-no-rows",
    RNPZ,
    "contain no present position",
    setup=_npz("t.npz", positions=np.zeros((0, 1, 2)), ids=np.arange(1), dt=np.float64(0.1)),
)
case(
    "npz-bad-meta",
    RNPZ,
    "array 'meta' is not JSON",
    setup=_npz(
        "t.npz",
        positions=np.zeros((1, 1, 2)),
        ids=np.arange(1),
        dt=np.float64(0.1),
        meta=np.str_("{not json"),
    ),
)
case(
    "npz-attr-shape",
    RNPZ,
    "attribute 'radius' must have shape (1,), got (2,)",
    setup=_npz(
        "t.npz",
        positions=np.zeros((1, 1, 2)),
        ids=np.arange(1),
        dt=np.float64(0.1),
        attr_radius=np.ones(2),
    ),
)
case(
    "npz-is-npy",
    RNPZ,
    "t.npz: not a crowdsim trajectories .npz",
    setup=lambda w, env: (np.save(w / "x.npy", np.zeros(3)), os.replace(w / "x.npy", w / "t.npz")),
)
case("npz-fps-override-bad", "render --trajectories {npz} --fps 0 --out {w}/seq", "got 0.0")

# --- evaluate ---------------------------------------------------------------------------
E = "evaluate {res} {seq}"
case(
    "eval-similarity-inf",
    f"{E} --similarity-px inf",
    "--similarity-px must be in (0, 1000] px, got inf",
)
case("eval-similarity-nan", f"{E} --similarity-px nan", "got nan")
case("eval-similarity-0", f"{E} --similarity-px 0", "got 0.0")
case("eval-similarity-neg", f"{E} --similarity-px -5", "got -5.0")
case("eval-similarity-huge", f"{E} --similarity-px 1e9", "got 1000000000.0")
case("eval-similarity-text", f"{E} --similarity-px wide", "'wide'")
case("eval-results-missing", "evaluate {w}/none.txt {seq}", "none.txt: no such results file")
case("eval-results-folder", "evaluate {seq} {seq}", "is a folder, not a MOT results file")
case("eval-seq-missing", "evaluate {res} {w}/noseq", "noseq: no such sequence folder")
case("eval-seq-is-file", "evaluate {res} {afile}", "afile: no such sequence folder")
case("eval-seq-no-seqinfo", "evaluate {res} {w}", "missing seqinfo.ini")
case("eval-plot-suffix", f"{E} --plot {{w}}/curve.jpg", "--plot must end in .png")
case("eval-plot-under-file", f"{E} --plot {{afile}}/curve.png", "afile is a file, not a folder")
case(
    "eval-plot-is-folder",
    f"{E} --plot {{w}}/c.png",
    "c.png: is a folder, not a file",
    setup=lambda w, env: (w / "c.png").mkdir(),
)
case(
    "eval-plot-into-seq",
    f"{E} --plot {{seq}}/curve.png",
    "would overwrite or sit inside the input SEQUENCE",
)
case(
    "eval-plot-sysfs",
    f"{E} --plot /sys/crowdsim-battery.png",
    "/sys/crowdsim-battery.png: permission denied",
)
case("eval-plot-readonly", f"{E} --plot {{ro}}/c.png", "is not writable", needs="ro")
case(
    "eval-plot-full-disk", f"{E} --plot {{full}}/c.png", "no space left on the device", needs="full"
)


def res_case(id: str, content: str, needle: str, **kw) -> None:
    case(id, "evaluate {w}/r.txt {seq}", needle, files=(("r.txt", content),), **kw)


res_case("eval-res-text", "1,1,a,b,c,d\n", "r.txt:1: non-numeric value 'a'")
res_case("eval-res-few-cols", "1,1,2\n", "r.txt:1: expected at least 6 columns")
res_case("eval-res-frame-0", "0,1,2,2,8,8\n", "r.txt:1: frame must be a positive integer")
res_case("eval-res-frame-float", "1.5,1,2,2,8,8\n", "got '1.5'")
res_case("eval-res-nan", "1,1,nan,2,8,8\n", "r.txt:1: non-finite value")
res_case("eval-res-neg-size", "1,1,2,2,-8,8\n", "box width/height must be >= 0")
res_case("eval-res-ragged", "1,1,2,2,8,8,1,1,1\n2,1,2,2,8,8\n", "r.txt:2: expected 9 columns")
res_case("eval-res-outside", "1,1,5000,5000,8,8\n", "point (5004.0, 5004.0) lies outside")
res_case("eval-res-beyond-length", "99,1,2,2,8,8\n", "99")
res_case("eval-res-id-float", "1,1.5,2,2,8,8\n", "id 1.5 is not a whole number")
res_case("eval-res-duplicate", "1,1,2,2,8,8\n1,1,3,3,8,8\n", "appears twice")
res_case("eval-res-id-huge", "1,1e30,2,2,8,8\n", "id 1e+30 is not a whole number below 2^53")


MOT_SEQ_CASES: list[tuple[str, Callable[[Path], None], str, bool]] = [
    # (name, edit of a copy of the sequence, needle, keep checksums.json)
    ("seqlength-0", _ini("seqLength", "0"), "'seqLength' must be >= 1, got 0", False),
    ("seqlength-neg", _ini("seqLength", "-4"), "'seqLength' must be >= 1, got -4", False),
    ("seqlength-text", _ini("seqLength", "ten"), "'seqLength' has a bad value 'ten'", False),
    (
        "seqlength-missing",
        lambda s: (
            _ini("seqLength", "")(s)
            or (s / "seqinfo.ini").write_text(
                (s / "seqinfo.ini").read_text().replace("seqLength=\n", "")
            )
        ),
        "missing key 'seqLength'",
        False,
    ),
    ("imwidth-0", _ini("imWidth", "0"), "'imWidth' must be a finite number > 0, got 0", False),
    ("imwidth-wrong", _ini("imWidth", "640"), "the image is 64x48 px&&imWidth=640", False),
    (
        "framerate-nan",
        _ini("frameRate", "nan"),
        "'frameRate' must be a finite number > 0, got nan",
        False,
    ),
    (
        "templatesize-0",
        _ini("templateSize", "0"),
        "'templateSize' must be in [2, 256] px, got 0",
        False,
    ),
    ("templatesize-5000", _ini("templateSize", "5000"), "got 5000", False),
    ("boxtype-bad", _ini("boxType", "feet"), "'boxType' must be head or body, got 'feet'", False),
    (
        "seqinfo-garbage",
        lambda s: (s / "seqinfo.ini").write_text("\x00garbage"),
        "seqinfo.ini: malformed",
        False,
    ),
    (
        "gt-beyond-length",
        _append_gt("99,1,2,2,8,8,1,1,1\n"),
        "frame 99 is beyond seqLength=6",
        False,
    ),
    ("gt-duplicate", _append_gt("1,1,2,2,12,12,1,1,1\n"), "frame 1, id 1 appears twice", False),
    ("gt-id-float", _append_gt("2,7.5,2,2,12,12,1,1,1\n"), "id 7.5 is not a whole number", False),
    (
        "gt-id-huge",
        _append_gt("2,1e30,2,2,12,12,1,1,1\n"),
        "id 1e+30 is not a whole number below 2^53",
        False,
    ),
    ("gt-text", _gt("1,1,x,2,12,12,1,1,1\n"), "non-numeric value 'x'", False),
    ("gt-frame-0", _gt("0,1,2,2,12,12,1,1,1\n"), "frame must be a positive integer", False),
    ("gt-empty", _gt(""), "no ground truth", False),
    ("img-missing", lambda s: (s / "img1" / "000003.jpg").unlink(), "000003.jpg", False),
    ("img-truncated", _truncate_jpeg, "000003.jpg", True),
    (
        "img-replaced",
        lambda s: shutil.copy(s / "img1" / "000001.jpg", s / "img1" / "000004.jpg"),
        "000004.jpg: damaged",
        True,
    ),
]
for _name, _edit, _needle, _keep in MOT_SEQ_CASES:
    _why = ""
    case(f"eval-{_name}", "evaluate {res} {w}/s", _needle, setup=seq_copy(_edit, _keep))
    case(
        f"track-{_name}",
        "track {w}/s --tracker ncc --no-progress --out {w}/r.txt",
        _needle,
        setup=seq_copy(_edit, _keep),
        xfail=_why,
    )
    case(  # the same readers and checks, before any cell runs
        f"compare-seq-{_name}",
        "compare --sequences {w}/s --trackers ncc --no-progress --out {w}/o",
        _needle,
        setup=seq_copy(_edit, _keep),
    )

# --- track ------------------------------------------------------------------------------
T = "track {seq} --tracker ncc --no-progress"
case("track-input-missing", "track {w}/none --out {w}/r.txt", "none: no such sequence folder")
case("track-frames-0", f"{T} --frames 0 --out {{w}}/r.txt", "--frames must be >= 1, got 0")
case("track-frames-neg", f"{T} --frames -3 --out {{w}}/r.txt", "got -3")
case(
    "track-template-1",
    f"{T} --template-size 1 --out {{w}}/r.txt",
    "--template-size must be in [2, 256] px, got 1",
)
case(
    "track-template-5000",
    f"{T} --template-size 5000 --out {{w}}/r.txt",
    "--template-size must be in [2, 256] px, got 5000",
)
case("track-tracker-unknown", "track {seq} --tracker magic --out {w}/r.txt", "'magic'")
case("track-out-under-file", f"{T} --out {{afile}}/r.txt", "afile&&is a file, not a folder")
case(
    "track-out-is-folder",
    f"{T} --out {{w}}/r",
    "r: is a folder, not a file",
    setup=lambda w, env: (w / "r").mkdir(),
)
case(
    "track-out-sysfs",
    f"{T} --out /sys/crowdsim-battery.txt",
    "/sys/crowdsim-battery.txt: permission denied",
)
case(
    "track-out-full-disk", f"{T} --out {{full}}/r.txt", "no space left on the device", needs="full"
)
case(
    "track-video-full-disk",
    f"{T} --out {{w}}/r.txt --video {{full}}/v.mp4",
    "v.mp4: OpenCV cannot write an MP4 video here",
    needs="full",
)
case(
    "track-detector-threshold-unused",
    f"{T} --out {{w}}/r.txt --detector-threshold 1.5",
    "--detector-threshold must be a finite number in (0, 1), got 1.5",
)
case(
    "track-detector-weights-unused-missing",
    f"{T} --out {{w}}/r.txt --detector-weights {{w}}/none.pt",
    "--detector-weights&&none.pt: no such file",
)
# a read-only folder is refused before any frame is tracked, naming the flag
case("track-out-readonly", f"{T} --out {{ro}}/r.txt", "--out&&is not writable", needs="ro")
case(
    "track-video-readonly",
    f"{T} --out {{w}}/r.txt --video {{ro}}/v.mp4",
    "--video&&is not writable",
    needs="ro",
)
case(
    "track-video-under-file",
    f"{T} --out {{w}}/r.txt --video {{afile}}/o.mp4",
    "afile&&is a file, not a folder",
)
case("track-video-ids-alone", f"{T} --out {{w}}/r.txt --video-ids", "--video-ids needs --video")
case(
    "track-evaluate-video",
    "track {w}/v.mp4 --evaluate --out {w}/r.txt",
    "--evaluate needs a sequence folder",
    files=(("v.mp4", b"\0" * 64),),
)
case(
    "track-video-garbage",
    "track {w}/v.mp4 --out {w}/r.txt --init {w}/i.csv",
    "v.mp4: not a readable video file",
    files=(("v.mp4", b"\0" * 64), ("i.csv", "id,x,y\n")),
)
case(
    "track-init-missing",
    f"{T} --init {{w}}/none.csv --out {{w}}/r.txt",
    "none.csv: no such points file",
)


def init_case(id: str, content: str, needle: str) -> None:
    case(id, f"{T} --init {{w}}/i.csv --out {{w}}/r.txt", needle, files=(("i.csv", content),))


init_case("track-init-header", "a,b,c\n1,2,3\n", "header must be 'frame,id,x,y' or 'id,x,y'")
init_case("track-init-text", "id,x,y\n1,a,3\n", "non-numeric value")
init_case("track-init-nan", "id,x,y\n1,nan,3\n", "non-finite value")
init_case("track-init-columns", "id,x,y\n1,2,3,4\n", "expected 3 columns, got 4")
init_case("track-init-unknown-id", "id,x,y\n77,2,3\n", "ids [77] are unknown")
init_case("track-init-id-2.5", "id,x,y\n2.5,2,3\n", "2.5")
init_case(
    "track-init-duplicate", "frame,id,x,y\n1,1,2,3\n1,1,4,5\n", "id 1 is listed more than once"
)
init_case("track-init-frame-2.5", "frame,id,x,y\n2.5,1,2,3\n", "2.5")

# --- generate ---------------------------------------------------------------------------
G = "generate --spec {w}/s.toml --out {w}/out --workers 1 --no-progress"


def spec_case(id: str, edit: Callable[[str], str], needle: str, **kw) -> None:
    def setup(w: Path, env: Env) -> None:
        (w / "s.toml").write_text(edit(SPEC))

    case(id, G, needle, setup=setup, **kw)


def _sub(old: str, new: str) -> Callable[[str], str]:
    def edit(text: str) -> str:
        assert old in text, old
        return text.replace(old, new)

    return edit


spec_case(
    "gen-warmup-1e8",
    _sub("warmup_steps = 0", "warmup_steps = 100000000"),
    "warmup_steps must be in [0, 100000], got 100000000",
)
spec_case(
    "gen-warmup-neg",
    _sub("warmup_steps = 0", "warmup_steps = -1"),
    "warmup_steps must be in [0, 100000], got -1",
)
spec_case("gen-warmup-float", _sub("warmup_steps = 0", "warmup_steps = 2.5"), "2.5")
spec_case("gen-frames-0", _sub("frames = 4", "frames = 0"), "frames must be in [1,")
spec_case("gen-frames-float", _sub("frames = 4", "frames = 4.5"), "4.5")
spec_case("gen-fps-0", _sub("fps = 25.0", "fps = 0.0"), "fps must be in [5, 1000], got 0.0")
spec_case("gen-fps-nan", _sub("fps = 25.0", "fps = nan"), "nan")
spec_case("gen-fps-2", _sub("fps = 25.0", "fps = 2.0"), "fps must be in [5, 1000], got 2.0")
spec_case(
    "gen-event-kind-list",
    lambda t: t + '\n[[events]]\nkind = ["stop"]\nstart = 1\n',
    "events[0].kind must be one of",
)
spec_case(
    "gen-agents-float",
    _sub("n_agents = 6", "n_agents = 6.5"),
    "marathon.n_agents must be an integer, got 6.5",
)
spec_case(
    "gen-camera-width-alone",
    _sub("max_width = 96", "max_width = 96\nwidth = 64"),
    "s.toml: camera.width needs camera.height (give both or neither)",
)
spec_case(
    "gen-camera-sees-nobody",
    _sub("max_width = 96", "max_width = 96\ncenter = [1000.0, 1000.0]"),
    "camera: no person is inside the",
)
spec_case("gen-seed-neg", _sub("seed = 1", "seed = -1"), "seed must be >= 0, got -1")
spec_case("gen-name-slash", _sub('name = "tiny"', 'name = "../evil"'), "'../evil'")
spec_case("gen-unknown-field", _sub("seed = 1", "seed = 1\nsede = 2"), "unknown field 'sede'")
spec_case("gen-unknown-scenario", _sub('name = "marathon"', 'name = "nosuch"'), "nosuch")
spec_case("gen-agents-0", _sub("n_agents = 6", "n_agents = 0"), "n_agents")
spec_case(
    "gen-template-5000",
    _sub("template_px = 8", "template_px = 5000"),
    "appearance.template_px must be an integer in [4, 64], got 5000",
)
spec_case(
    "gen-max-width-huge",
    _sub("max_width = 96", "max_width = 100000"),
    "camera.max_width must be in [8, 8192], got 100000",
)
spec_case(
    "gen-max-width-largest",
    _sub("max_width = 96", "max_width = 16384\nwidth = 16384\nheight = 16384"),
    "must be in [8, 8192], got 16384",
)
spec_case("gen-toml-broken", _sub("seed = 1", "seed = = 1"), "s.toml")
spec_case(  # dense trajectories of 1e6 frames x 2000 people: refused, not simulated for hours
    "gen-frames-agents-memory",
    lambda t: _sub("n_agents = 6", "n_agents = 2000")(_sub("frames = 4", "frames = 1000000")(t)),
    "s.toml: frames = 1000000 (+ warmup_steps = 0) with scenario.n_agents = 2000",
)
spec_case(  # its trajectories fit (5.7 GiB), its rendering would not: refused before any step
    "gen-frames-agents-render-memory",
    lambda t: _sub("n_agents = 6", "n_agents = 2000")(_sub("frames = 4", "frames = 9000")(t)),
    "(8,525 people), simulated and rendered at up to 96x64 px needs about 13.7 GiB",
)
spec_case(
    "gen-ppm-1e9",
    _sub("[camera]", "[camera]\npx_per_m = 1e9"),
    "camera.px_per_m must be in [0.001, 10000], got 1e+09",
)
case("gen-spec-missing", "generate --spec {w}/none.toml --out {w}/out", "none.toml")
case(
    "gen-frames-flag-0",
    "generate --spec {spec} --out {w}/out --frames 0",
    "--frames must be >= 1, got 0",
)
case(
    "gen-workers-0",
    "generate --spec {spec} --out {w}/out --workers 0",
    "--workers must be an integer in [1, 256], got 0",
)
case(
    "gen-workers-above-cores",
    "generate --spec {spec} --out {w}/out --workers 4097",
    "--workers must be an integer in [1, 256], got 4097",
)
case(
    "gen-workers-local-above-cores",
    "generate --spec {spec} --out {w}/out --workers 256",
    "--workers must be in [1, &&(os.cpu_count()), got 256",
)
case(
    "gen-only-without-suite",
    "generate --spec {spec} --only seq1 --out {w}/out",
    "--only needs --suite",
)
case("gen-only-unknown", "generate --suite ucf9 --only seq99 --out {w}/out", "seq99")
case(
    "gen-address-local",
    "generate --spec {spec} --address x:1 --out {w}/out",
    "--address needs --backend ray",
)
case(
    "gen-out-is-file",
    "generate --spec {spec} --out {afile}",
    "--out must be a folder, got the file",
)
case(
    "gen-spec-folder",
    "generate --spec {w} --out {w}/x",
    "is a folder; a folder of spec files is --suite",
)
case(
    "gen-out-under-file", "generate --spec {spec} --out {afile}/x", "afile is a file, not a folder"
)
case(  # a manifest, its lock and a sequence written into a sequence: no longer provably ours
    "gen-out-in-sequence",
    "generate --spec {spec} --out {seq} --workers 1 --no-progress",
    "lies in a sequence folder",
)
case("gen-out-sysfs", "generate --spec {spec} --out /sys/crowdsim-battery", "/sys/crowdsim-battery")
case(
    "gen-out-readonly",
    "generate --spec {spec} --out {ro}/out --no-progress",
    "read-only file system",
    needs="ro",
)
case(
    "gen-out-full-disk",
    "generate --spec {spec} --out {full}/out --workers 1 --no-progress",
    "no space left on the device",
    needs="full",
)
case(
    "gen-tmp-lookalike-kept",
    "generate --spec {spec} --out {w}/out --frames 0",
    "--frames must be >= 1",
    files=(("out/.tmp-notes-2024/thesis.txt", "mine\n"),),
)

# --- demo -------------------------------------------------------------------------------
case("demo-out-is-file", "demo --out {afile}", "afile: is a file, not a folder")
case("demo-out-under-file", "demo --out {afile}/demo", "afile is a file, not a folder")
case("demo-out-sysfs", "demo --out /sys/crowdsim-battery", "/sys/crowdsim-battery")
case("demo-out-readonly", "demo --out {ro}/demo", "/ro is not writable", needs="ro")
case("demo-frames-0", "demo --out {w}/d --frames 0 --no-progress", "--frames must be in [2, 100]")
case(
    "demo-frames-past-the-sequence",
    "demo --out {w}/d --frames 101 --no-progress",
    "(the demo sequence's length), got 101",
)
case("demo-frames-text", "demo --out {w}/d --frames few", "'few'")

# --- detector and train: flags named as given, not as the config field behind them ----------
case("detector-train-iterations-0", "detector train --out {w}/d --iterations 0", "--iterations")
case("detector-eval-threshold-2", "detector eval --threshold 2 --out {w}/e", "--threshold must be")
case("detector-eval-tracker", "detector eval --tracker nosuch --out {w}/e", "tracker 'nosuch'")
case(
    "detector-eval-tracking-frames-alone",
    "detector eval --tracking-frames 20 --out {w}/e",
    "--tracking-frames needs --tracking",
)
case(
    "detector-eval-tracking-frames-1",
    "detector eval --tracking --tracking-frames 1 --out {w}/e",
    "--tracking-frames must be",
)
case(
    "detector-eval-out-is-file",
    "detector eval --out {afile}",
    "afile: is a file, not a folder",
)
case("train-candidates-0", "train --algo scene --candidates 0 --out {w}/o", "--candidates must be")

case("bench-no-name", "bench", "crowdsim bench: error: name a benchmark: sim, fd")
case(
    "cli-unknown-flag-names-the-command",
    "detector train --bogus 1 --out {w}/d",
    "crowdsim detector train: error: unrecognized arguments: --bogus 1",
)

# --- bench: every number checked, and every output path, before any run --------------------
BENCH = (
    (
        "bench-sim-scale-neg",
        "sim --sizes 10 --peers none --scale -1",
        "--scale must be an integer in [0, 1000000], got -1",
    ),
    (
        "bench-sim-split-neg",
        "sim --sizes 10 --peers none --workers 1 --split-sizes -4",
        "--split-sizes must be integers in [1, 1000000], got '-4'",
    ),
    (
        "bench-sim-json-under-file",
        "sim --sizes 10 --peers none --json-out {afile}/x.json",
        "afile is a file, not a folder",
    ),
    (
        "bench-fd-length-inf",
        "fd --densities 1 --length inf",
        "--length must be a finite number in (0, 10000], got inf",
    ),
    (
        "bench-fd-warmup-inf",
        "fd --densities 1 --warmup inf",
        "--warmup must be a finite number",
    ),
    (
        "bench-fd-crowd-huge",
        "fd --densities 6 --length 9000 --width 9000",
        "holds 4.86e+08 people, more than the 1000000",
    ),
    (
        "bench-fd-seed-neg",
        "fd --densities 1 --seed -1",
        "--seed must be an integer >= 0, got -1",
    ),
    (
        "bench-track-template-0",
        "track --targets 5 --frames 2 --template 0",
        "--template must be an integer in [4, 64], got 0",
    ),
    (
        "bench-track-frame-0x0",
        "track --targets 5 --frames 2 --sampling-frame 0x0",
        "--sampling-frame must look like 480x270",
    ),
    (
        "bench-track-targets-0",
        "track --targets 0 --frames 2",
        "--targets must be an integer in [1, 100000], got 0",
    ),
    (
        "bench-solver-seed-neg",
        "solver --seed -1",
        "--seed must be an integer >= 0, got -1",
    ),
    (
        "bench-solver-max-iter-0",
        "solver --max-iter 0",
        "--max-iter must be an integer >= 1, got 0",
    ),
    (
        "bench-solver-npz-under-file",
        "solver --save-npz {afile}/q.npz",
        "afile is a file, not a folder",
    ),
    (
        "bench-solver-npz-suffix",
        "solver --sizes 10 --save-npz {w}/q",
        "--save-npz must end in .npz, got",
    ),
    ("bench-solver-eps-neg", "solver --eps -1", "--eps must be a finite number >= 0, got -1.0"),
    (  # 5 steps gave a NaN speed (and NaN in fd.json), 0 a pandas "All arrays must be ..."
        "bench-fd-measure-short",
        "fd --densities 1 --measure 0.2 --out {w}/o",
        "--measure must be at least 0.24 s (6 steps of 0.04 s: PedPy's speeds span 5), got 0.2",
    ),
    (  # it ran a 6.5 m corridor and printed the 1 /m² target beside a density of 0.06
        "bench-fd-length-short",
        "fd --densities 1 --length 1 --out {w}/o",
        "--length must be a finite number >= 6.5, got 1.0",
    ),
    (  # named counterflow.width, a scenario the command line never mentions
        "bench-fd-width-narrow",
        "fd --densities 1 --width 0.3 --out {w}/o",
        "--width must be a finite number >= 0.7, got 0.3",
    ),
    ("bench-fd-measure-none", "fd --densities 1 --measure 0.01 --out {w}/o", "got 0.01"),
    ("bench-render-seed-neg", "render --seed -1", "--seed must be an integer >= 0, got -1"),
    ("bench-render-template-1", "render --template-px 1", "--template-px must be an integer in"),
    ("bench-envs-vector-steps-0", "envs --vector-steps 0", "--vector-steps must be >= 1, got 0"),
    ("bench-envs-targets-0", "envs --targets 0", "--targets must be >= 1, got 0"),
    (
        "bench-envs-cache-under-file",
        "envs --episode-cache {afile}/c",
        "--episode-cache {afile}/c: {afile} is a file, not a folder",
    ),
)
for cid, argv, needle in BENCH:
    case(cid, f"bench {argv}", needle)
case(  # the one wording of every command, not Python's "[Errno 28] ..."
    "bench-fd-full-disk",
    "bench fd --densities 1 --length 6.5 --width 3 --warmup 0.2 --measure 0.24 --lane-seconds 0.2 "
    "--out {full}/b",
    "fd.png: no space left on the device",
    needs="full",
)

# --- global -----------------------------------------------------------------------------
case("cli-unknown-command", "frobnicate", "'frobnicate'")
case("cli-no-command", [], "COMMAND")
case("cli-unknown-flag", f"{SIM} --frobnicate", "--frobnicate")

case("cli-track-out-empty", ["track", "{seq}", "--out", ""], "--out must name a file or folder")
case("cli-demo-out-empty", ["demo", "--out", ""], "--out: must name a file or folder, got ''")
case(
    "cli-simulate-plot-blank",
    ["simulate", "marathon", "--plot", " "],
    "--plot: must name a file or folder, got ' '",
)
case(
    "cli-bench-save-npz-empty",
    ["bench", "solver", "--save-npz", ""],
    "--save-npz must name a file or folder, got ''",
)
case("cli-compare-suite-empty", ["compare", "--suite", "", "--out", "{w}/o"], "--suite must name")
