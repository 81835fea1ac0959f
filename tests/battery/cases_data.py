"""Bad input to the data side (issue 13): ``render`` and ``generate --overwrite`` against
folders crowdsim cannot prove it wrote, spec files, points CSVs for ``track --init``,
``simulate`` flags, and the Python API of the trackers, specs, appearance, camera and readers.

Cases that only repeat one in ``cases_cli.py`` or ``cases_ownership.py`` are left out.
"""

from __future__ import annotations

import shutil
from collections.abc import Callable
from pathlib import Path

import numpy as np

from battery.harness import SPEC, Env, api_case, case

# --- render --overwrite: replace only what crowdsim provably wrote -----------------------
R = "render --trajectories {csv} --fps 10 --size 64x48 --overwrite --out {w}/o"


def _seq(edit: Callable[[Path, Env], None]) -> Callable[[Path, Env], None]:
    """A copy of the shared crowdsim sequence at ``{w}/o``, then ``edit(o, env)``."""

    def setup(w: Path, env: Env) -> None:
        shutil.copytree(env.seq, w / "o")
        edit(w / "o", env)

    return setup


def _suite(edit: Callable[[Path, Env], None], manifest: str) -> Callable[[Path, Env], None]:
    """A suite folder ``{w}/o`` (``manifest.json`` + the shared sequence), then ``edit``."""

    def setup(w: Path, env: Env) -> None:
        shutil.copytree(env.seq, w / "o" / "seq")
        (w / "o" / "manifest.json").write_text(manifest)
        edit(w / "o", env)

    return setup


OUR_MANIFEST = '{"format": 1, "sequences": {}}'
case(
    "data-render-overwrite-foreign-manifest",
    R,
    "manifest.json is not a crowdsim manifest",
    setup=_suite(lambda o, env: None, '{"name": "my-app", "version": "1.0"}'),
)
case(
    "data-render-overwrite-suite-notes",
    R,
    "o/notes.txt was not written by crowdsim",
    setup=_suite(lambda o, env: (o / "notes.txt").write_text("mine"), OUR_MANIFEST),
)
case(
    "data-render-overwrite-suite-user-folder",
    R,
    "o/drafts has no checksums.json",
    setup=_suite(
        lambda o, env: ((o / "drafts").mkdir(), (o / "drafts" / "plan.md").write_text("mine")),
        OUR_MANIFEST,
    ),
)
case(
    "data-render-overwrite-suite-link",
    R,
    "o/elsewhere is a link, not a folder crowdsim wrote",
    setup=_suite(lambda o, env: (o / "elsewhere").symlink_to(env.seq), OUR_MANIFEST),
)
case(
    "data-render-overwrite-empty-user-folder",
    R,
    "o/annotations was not written by crowdsim",
    setup=_seq(lambda o, env: (o / "annotations").mkdir()),
)
case(
    "data-render-overwrite-link-out",
    R,
    "img1/extra.jpg was not written by crowdsim",
    setup=_seq(lambda o, env: (o / "img1" / "extra.jpg").symlink_to(env.csv)),
)
case(
    "data-render-overwrite-broken-listing",
    R,
    "checksums.json: not valid JSON",
    setup=_seq(lambda o, env: (o / "checksums.json").write_text("{not json")),
)
case(
    "data-render-overwrite-missing-frame",
    R,
    "000003.jpg: missing (listed in checksums.json)",
    setup=_seq(lambda o, env: (o / "img1" / "000003.jpg").unlink()),
)
case(
    "data-render-overwrite-changed-seqinfo",
    R,
    "seqinfo.ini: damaged",
    setup=_seq(lambda o, env: (o / "seqinfo.ini").write_text("[Sequence]\nname=mine\n")),
)
case(
    "data-render-template-float",
    "render --trajectories {csv} --fps 10 --template-px 8.5 --out {w}/o",
    "'8.5'",
)

# --- generate --overwrite: a sequence inside the output folder ---------------------------
G = "generate --spec {spec} --out {w}/out --workers 1 --no-progress --overwrite"


def _in_out(edit: Callable[[Path], None]) -> Callable[[Path, Env], None]:
    """``{w}/out/tiny``: a crowdsim sequence of another spec (so ``--overwrite`` would replace
    it), then ``edit`` plants a user's change."""

    def setup(w: Path, env: Env) -> None:
        shutil.copytree(env.seq, w / "out" / "tiny")
        edit(w / "out" / "tiny")

    return setup


case(
    "data-gen-overwrite-img1-file",
    G,
    "tiny/img1/000001_blurred.jpg was not written by crowdsim",
    setup=_in_out(lambda s: (s / "img1" / "000001_blurred.jpg").write_bytes(b"\xff\xd8mine")),
)
case(
    "data-gen-overwrite-hidden-file",
    G,
    "tiny/.DS_Store was not written by crowdsim",
    setup=_in_out(lambda s: (s / ".DS_Store").write_bytes(b"\0\0\0\1Bud1")),
)
case(
    "data-gen-overwrite-edited-gt",
    G,
    "gt.txt: damaged",
    setup=_in_out(
        lambda s: (s / "gt" / "gt.txt").write_text(
            (s / "gt" / "gt.txt").read_text() + "1,9,1,1,12,12,1,1,1\n"
        )
    ),
)


def _user_folder(w: Path, env: Env) -> None:
    (w / "out" / "tiny").mkdir(parents=True)
    (w / "out" / "tiny" / "thesis.tex").write_text("\\chapter{One}\n")


case(
    "data-gen-overwrite-user-folder",
    G,
    "tiny has no checksums.json, so crowdsim cannot tell its files from yours",
    setup=_user_folder,
)


# --- generate: spec files ----------------------------------------------------------------
def gen_spec(id: str, name: str, content: str | bytes, needle: str) -> None:
    case(
        id,
        f"generate --spec {{w}}/{name} --out {{w}}/out --workers 1 --no-progress",
        needle,
        files=((name, content),),
    )


gen_spec("data-gen-spec-yaml-list", "s.yaml", "- name: tiny\n- seed: 1\n", "a spec must be a table")
gen_spec("data-gen-spec-json", "s.json", '{"name": "tiny"}', "s.json: spec files must end in .toml")
gen_spec("data-gen-spec-binary", "s.toml", b"\x00\xff\xfe\x00", "s.toml")
gen_spec(
    "data-gen-margin-huge",
    "s.toml",
    SPEC.replace("[camera]", "[camera]\nmargin_m = 1e6"),
    "camera.margin_m must be in [0, 1000], got 1000000.0",
)
gen_spec(
    "data-gen-ground-margin-negative",
    "s.toml",
    SPEC.replace("[camera]", "[camera]\nground_margin_px = -3"),
    "camera.ground_margin_px must be an integer in [0, 16384], got -3",
)
gen_spec(
    "data-gen-output-none",
    "s.toml",
    SPEC + "\n[output]\nimages = false\n",
    "output.images and output.video cannot both be false",
)
gen_spec(
    "data-gen-scenario-string",
    "s.toml",
    SPEC.split("[scenario]")[0].replace('name = "tiny"', 'name = "tiny"\nscenario = "marathon"'),
    "scenario must be a table, got 'marathon'",
)
gen_spec(
    "data-gen-calibration-table",
    "s.toml",
    SPEC + "\n[calibration.paper]\nncc = 58.0\n",
    "calibration.paper must be a number, string or list",
)
gen_spec(
    "data-gen-appearance-typo",
    "s.toml",
    SPEC.replace("template_px = 8", "template_px = 8\nnosie_sigma = 2.0"),
    "unknown field 'appearance.nosie_sigma' (did you mean 'noise_sigma'?)",
)

# --- track --init: points CSVs -------------------------------------------------------------
T = "track {seq} --tracker ncc --no-progress --out {w}/r.txt --init {w}/i.csv"
for cid, content, needle in (
    ("data-track-init-id-huge", "id,x,y\n1e30,2,3\n", "i.csv:2: frame and id must be below 2**53"),
    ("data-track-init-outside", "id,x,y\n1,5000,3\n", "id 1 starts outside the 64x48 image"),
    ("data-track-init-negative", "id,x,y\n1,-5,3\n", "at (-5.0, 3.0)"),
    ("data-track-init-semicolons", "id;x;y\n1;2;3\n", "header must be 'frame,id,x,y' or 'id,x,y'"),
    ("data-track-init-birth-unknown", "frame,id,x,y\n1,1,2,3\n2,7,1,1\n", "ids [7] are unknown"),
    (
        "data-track-init-detections",
        "frame,detection,x,y\n1,1,2,3\n2,2,3,3\n",
        "i.csv: per-frame detections (crowdsim detect --frames N or --all)",
    ),
):
    case(cid, T, needle, files=(("i.csv", content),))

# --- simulate ------------------------------------------------------------------------------
case("data-sim-agents-float", "simulate marathon --agents 2.5 --steps 2", "'2.5'")
case("data-sim-density-neg", "simulate marathon --agents 4 --steps 2 --density -1", "got -1.0")


# --- the trackers' Python API ----------------------------------------------------------------
FRAME = np.zeros((32, 32, 3), np.uint8)
POINT = np.array([[9.0, 9.0]])


def _make(name, params=None, **kw):
    def call(w: Path, env: Env):
        from tracker.registry import make_tracker

        return make_tracker(name, params=params, **kw)

    return call


def _detector(**kw):
    def call(w: Path, env: Env):
        from synth_data.detections import DetectionParams

        return DetectionParams(**kw)

    return call


api_case("data-api-make-params-str", _make("bqp", "zeta=1"), "takes params as a BQPParams&&str")
api_case(
    "data-api-make-object-with-params",
    lambda w, env: _make(_make("ncc")(w, env), {"search_factor": 3.0})(w, env),
    "pass params only with a tracker name",
)
api_case("data-api-bqp-history-1", _make("bqp", history=1), "BQPParams.history&&[2, 1000]&&got 1")
api_case("data-api-bqp-zeta-nan", _make("bqp", zeta=float("nan")), "BQPParams.zeta&&nan")
api_case("data-api-bqp-extrema-float", _make("bqp", n_extrema=2.5), "n_extrema&&got 2.5")
api_case("data-api-bqp-fw-iter-huge", _make("bqp", fw_max_iter=10**9), "fw_max_iter&&[1, 10000]")
api_case("data-api-pnmc-patch-huge", _make("pnmc", flow_patch=10**6), "flow_patch&&[2, 64]")
api_case("data-api-pnmc-samples-huge", _make("pnmc", gmm_samples=10**9), "gmm_samples&&got")
api_case("data-api-meanshift-iter-huge", _make("meanshift", max_iter=10**6), "max_iter&&[1, 1000]")
api_case("data-api-detector-box-huge", _detector(box_px=1e9), "DetectionParams.box_px&&[1, 4096]")
api_case(
    "data-api-bytetrack-miss-rate", _make("bytetrack", miss_rate=0.3), "no parameter(s) miss_rate"
)
api_case("data-api-ocsort-delta-huge", _make("ocsort", delta_t=10**6), "delta_t&&[1, 100]")


def _init(**kw):
    def call(w: Path, env: Env):
        from tracker.registry import make_tracker

        args = {"frame": FRAME, "ids": [1], "points": POINT, "template_size": 8, **kw}
        make_tracker("ncc").init(**args)

    return call


api_case("data-api-init-template-1", _init(template_size=1), "template_size&&got 1")
api_case("data-api-init-points-flat", _init(points=np.array([9.0, 9.0])), "points&&got (2,)")
api_case("data-api-init-ids-mismatch", _init(ids=[1, 2]), "points must have shape (2, 2)")
api_case("data-api-init-frame-float", _init(frame=np.zeros((32, 32, 3))), "uint8&&float64")
api_case(
    "data-api-init-dup-ids",
    _init(ids=[1, 1], points=np.array([[9.0, 9.0], [20.0, 20.0]])),
    "duplicate ids [1]",
)
api_case("data-api-init-nan-point", _init(points=np.array([[np.nan, 9.0]])), "finite")
api_case("data-api-init-outside", _init(points=np.array([[90.0, 9.0]])), "at (90.0, 9.0)")


def _running(then: Callable[[object], object]):
    def call(w: Path, env: Env):
        from tracker.registry import make_tracker

        tr = make_tracker("ncc")
        tr.init(FRAME, [1], POINT, 8)
        return then(tr)

    return call


def _bqp_params():
    from tracker.bqp.params import BQPParams

    return BQPParams()


api_case(
    "data-api-step-size-changed",
    _running(lambda tr: tr.step(np.zeros((16, 16, 3), np.uint8))),
    "16x16, expected 32x32",
)
api_case(
    "data-api-set-params-dict",
    _running(lambda tr: tr.set_params({"search_factor": 3.0})),
    "takes NCCParams, got dict",
)
api_case(
    "data-api-set-params-other",
    _running(lambda tr: tr.set_params(_bqp_params())),
    "takes NCCParams, got BQPParams",
)
api_case(
    "data-api-birth-reused-id",
    _running(lambda tr: tr.step(FRAME, births=(np.array([1]), np.array([[3.0, 3.0]])))),
    "ids [1] were already used",
)
api_case(
    "data-api-birth-shape",
    _running(lambda tr: tr.step(FRAME, births=(np.array([2, 3]), np.array([[3.0, 3.0]])))),
    "births: points must have shape (2, 2)",
)


# --- specs, appearance, camera, readers ------------------------------------------------------
def _spec(data):
    def call(w: Path, env: Env):
        from synth_data.spec import spec_from_dict

        return spec_from_dict(data, source="s.toml")

    return call


BASE = {"name": "a", "seed": 1, "frames": 2, "scenario": {"name": "marathon", "n_agents": 4}}
api_case("data-api-spec-list", _spec([1, 2]), "s.toml: a spec must be a table/mapping, got list")
api_case("data-api-spec-name-empty", _spec({**BASE, "name": ""}), "s.toml: name must be&&got ''")
api_case("data-api-spec-seed-bool", _spec({**BASE, "seed": True}), "seed must be an integer")
api_case(
    "data-api-spec-center-3",
    _spec({**BASE, "camera": {"center": [1, 2, 3]}}),
    "camera.center must be two numbers, got [1, 2, 3]",
)
api_case(
    "data-api-spec-agents-huge",
    _spec({**BASE, "scenario": {"name": "marathon", "n_agents": 10**9}}),
    "n_agents&&got 1000000000",
)
api_case(
    "data-api-spec-scenario-typo",
    _spec({**BASE, "scenario": {"name": "marathon", "nagents": 5}}),
    "unknown parameter(s) for scenario 'marathon': nagents",
)


def _new(module: str, name: str, *args, **kw):
    def call(w: Path, env: Env):
        import importlib

        return getattr(importlib.import_module(module), name)(*args, **kw)

    return call


AM = "crowdsim.appearance_model"


def _appearance_from(values: dict):
    def call(w: Path, env: Env):
        from crowdsim.appearance_model import AppearanceParams

        return AppearanceParams.from_dict(values)

    return call


api_case(
    "data-api-appearance-typo", _appearance_from({"nosie": 1}), "appearance: unknown field 'nosie'"
)
api_case(
    "data-api-appearance-heads-str",
    _new(AM, "AppearanceParams", heads_on_top="yes"),
    "heads_on_top must be true or false, got 'yes'",
)
api_case("data-api-encoding-kbps-nan", _new(AM, "Encoding", video_kbps=float("nan")), "got nan")
api_case(
    "data-api-encoding-kbps-huge",
    _new(AM, "Encoding", video_kbps=1e12),
    "video_kbps&&got 1000000000000.0",
)
CAM = {"px_per_m": 10.0, "width": 64, "height": 48}
api_case(
    "data-api-camera-tilt-90",
    _new("crowdsim.camera", "Camera", **{**CAM, "tilt_deg": 90.0}),
    "camera.tilt_deg must be in [0, 60), got 90.0",
)
api_case(
    "data-api-camera-ppm-nan",
    _new("crowdsim.camera", "Camera", **{**CAM, "px_per_m": float("nan")}),
    "camera.px_per_m&&got nan",
)
api_case(
    "data-api-read-sequence-file",
    lambda w, env: _new("synth_data.mot", "read_sequence", env.afile)(w, env),
    "afile: no such sequence folder",
)
api_case(
    "data-api-write-mot-shape",
    lambda w, env: _new("synth_data.mot", "write_mot", w / "gt.txt", np.zeros((2, 3)))(w, env),
    "gt.txt: MOT rows must have shape (K, >= 9), got (2, 3)",
)


def _points(content: str):
    def call(w: Path, env: Env):
        from synth_data.births import read_points_csv

        (w / "p.csv").write_text(content)
        try:
            return read_points_csv(w / "p.csv")
        finally:
            (w / "p.csv").unlink()

    return call


api_case("data-api-points-frame-huge", _points("frame,id,x,y\n1e17,1,2,3\n"), "below 2**53")
api_case(
    "data-api-generate-backend",
    _new("synth_data.generate", "generate", [], "unused", backend="slurm"),
    "--backend must be local or ray, got 'slurm'",
)
