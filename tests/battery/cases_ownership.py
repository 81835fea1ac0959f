"""Bad input to render, generate, track (points CSV), the sequence readers, the spec and
appearance parameter sets, and the trackers' Python API (issue 13)."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np

from battery.harness import GOOD_CSV, SPEC, Env, api_case, case, seq_copy

# --- overwrite keeps what is not ours ----------------------------------------------------
RENDER = "render --trajectories {csv} --fps 10 --size 64x48 --overwrite --out {w}/o"


def _ours_with(extra: str, content: str = "mine"):
    """A sequence rendered by crowdsim into ``{w}/o``, then a user's file at ``o/<extra>``."""

    def setup(w: Path, env: Env) -> None:
        from crowdsim.cli import main

        assert main(["render", "--trajectories", str(env.csv), "--fps", "10", "--size", "64x48",
                     "--no-progress", "--out", str(w / "o")] if False else
                    ["render", "--trajectories", str(env.csv), "--fps", "10", "--size",
                     "64x48", "--out", str(w / "o")]) == 0  # fmt: skip
        p = w / "o" / extra
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_text(content)

    return setup


for cid, extra in (
    ("own-overwrite-user-gt", "gt/labels.txt"),
    ("own-overwrite-user-img1", "img1/000001_fixed.jpg"),
    ("own-overwrite-hidden", ".notes"),
    ("own-overwrite-nested", "gt/mine/deep.txt"),
):
    case(
        cid, RENDER, f"{extra.split('/')[-1]} was not written by crowdsim", setup=_ours_with(extra)
    )


def _edited_gt(w: Path, env: Env) -> None:
    _ours_with("gt/gt.txt", "1,1,1,1,12,12,1,1,1\n")(w, env)


case("own-overwrite-changed-gt", RENDER, "gt.txt: damaged", setup=_edited_gt)


def _no_checksums(w: Path, env: Env) -> None:
    shutil.copytree(env.seq, w / "o")
    (w / "o" / "checksums.json").unlink()


case("own-overwrite-no-checksums", RENDER, "has no checksums.json", setup=_no_checksums)


def _suite_with_hidden(w: Path, env: Env) -> None:
    shutil.copytree(env.seq, w / "o" / "seq")
    (w / "o" / "manifest.json").write_text('{"format": 1, "sequences": {}}')
    (w / "o" / ".hidden_notes").write_text("mine")


case(
    "own-overwrite-suite-hidden", RENDER, ".hidden_notes was not written", setup=_suite_with_hidden
)


def _checksums_outside(w: Path, env: Env) -> None:
    shutil.copytree(env.seq, w / "o")
    listing = json.loads((w / "o" / "checksums.json").read_text())
    listing["../../walk.csv"] = "0" * 64
    (w / "o" / "checksums.json").write_text(json.dumps(listing))


case(
    "own-overwrite-checksums-outside",
    RENDER,
    "entry '../../walk.csv' points outside the sequence folder",
    setup=_checksums_outside,
)
case(
    "own-track-checksums-outside",
    "track {w}/o --tracker ncc --no-progress --out {w}/r.txt",
    "points outside the sequence folder",
    setup=_checksums_outside,
)

# --- generate --overwrite into a sequence holding a user's file --------------------------
GEN = "generate --spec {w}/s.toml --out {w}/out --workers 1 --no-progress --overwrite"


def _generated_then_user_file(w: Path, env: Env) -> None:
    from crowdsim.cli import main

    (w / "s.toml").write_text(SPEC)
    argv = ["generate", "--spec", str(w / "s.toml"), "--out", str(w / "out"), "--workers", "1"]
    assert main([*argv, "--no-progress"]) == 0
    (w / "out" / "tiny" / "gt" / "notes.txt").write_text("mine")
    (w / "s.toml").write_text(SPEC.replace("seed = 1", "seed = 2"))


case(
    "own-generate-overwrite-user-file",
    GEN,
    "notes.txt was not written by crowdsim",
    setup=_generated_then_user_file,
)

# --- a manifest.json or tune_jobs.json that crowdsim did not write is never replaced ------
GEN_NEW = "generate --spec {w}/s.toml --out {w}/out --workers 1 --no-progress"
FOREIGN = "not a crowdsim manifest&&refusing to replace it"
for cid, content in (
    ("own-generate-foreign-manifest-text", "my own notes on this data\n"),
    ("own-generate-foreign-manifest-json", '{"project": "mine", "owner": "me"}'),
    ("own-generate-foreign-manifest-format", '{"format": 7, "sequences": {}}'),
):
    case(
        cid,
        GEN_NEW,
        "out/manifest.json: " + FOREIGN,
        files=(("s.toml", SPEC), ("out/manifest.json", content)),
    )
case(
    "own-demo-foreign-sequences-manifest",
    "demo --no-progress --out {w}/d",
    "sequences/manifest.json: " + FOREIGN,
    files=(("d/sequences/manifest.json", "mine\n"),),
)

# --- points CSV and track ----------------------------------------------------------------
T = "track {seq} --tracker ncc --no-progress --out {w}/r.txt --init {w}/i.csv"
for cid, content, needle in (
    ("own-init-only-header", "frame,id,x,y\n", "i.csv: no target in the first frame"),
    ("own-init-only-later", "frame,id,x,y\n3,1,10,12\n", "no target in the first frame"),
    ("own-init-blank-rows", "id,x,y\n\n\n", "no target in the first frame"),
    ("own-init-frame-0", "frame,id,x,y\n0,1,10,12\n", "frame must be a positive integer"),
    ("own-init-beyond", "frame,id,x,y\n1,1,10,12\n99,2,1,1\n", "frame 99 is beyond the 6"),
    ("own-init-inf", "id,x,y\n1,inf,3\n", "non-finite value"),
    ("own-init-utf16", "\ufeffid,x,y\n".encode("utf-16"), "i.csv"),
):
    case(cid, T, needle, files=(("i.csv", content),))

case(
    "own-track-damaged-frame",
    "track {w}/s --tracker ncc --no-progress --out {w}/r.txt",
    "000002.jpg: damaged",
    setup=seq_copy(lambda s: (s / "img1" / "000002.jpg").write_bytes(b"\xff\xd8junk"), True),
)


# --- sequence readers ---------------------------------------------------------------------
def _read(path: str):
    from synth_data.mot import read_sequence

    return lambda w, env: read_sequence(w / path if path != "{seq}" else env.seq).births()


def _check_listing(content: str):
    def call(w: Path, env: Env) -> None:
        from synth_data.mot import check_checksums

        shutil.copytree(env.seq, w / "s")
        (w / "s" / "checksums.json").write_text(content)
        try:
            check_checksums(w / "s")
        finally:
            shutil.rmtree(w / "s")

    return call


api_case("own-api-read-missing", _read("none"), "none: no such sequence folder")
api_case("own-api-checksums-list", _check_listing("[1, 2]"), "expected a non-empty object")
api_case("own-api-checksums-empty", _check_listing("{}"), "expected a non-empty object")
api_case("own-api-checksums-binary", _check_listing("\x00\x01"), "not valid JSON")
api_case(
    "own-api-checksums-absolute",
    _check_listing('{"/etc/hostname": "00"}'),
    "entry '/etc/hostname' points outside",
)
api_case(
    "own-api-checksums-digest-type",
    _check_listing('{"seqinfo.ini": 5}'),
    "entry 'seqinfo.ini' has no SHA-256 string",
)


def _births(content: str):
    def call(w: Path, env: Env):
        from synth_data.births import births_from_init

        (w / "p.csv").write_text(content)
        try:
            return births_from_init(w / "p.csv", 6)
        finally:
            (w / "p.csv").unlink()

    return call


api_case("own-api-births-header-only", _births("frame,id,x,y\n"), "no target in the first frame")
api_case("own-api-births-empty", _births(""), "empty points file")


# --- specs, appearance, encoding ------------------------------------------------------------
def _spec(**changes):
    def call(w: Path, env: Env):
        import tomllib

        from synth_data.spec import spec_from_dict

        data = tomllib.loads(SPEC)
        for key, value in changes.items():
            section, _, field = key.rpartition("__")
            (data.setdefault(section, {}) if section else data)[field] = value
        return spec_from_dict(data, source="s.toml")

    return call


api_case("own-api-spec-kbps-tiny", _spec(appearance__video_kbps=1e-9), "video_kbps must be 0 (off)")
api_case("own-api-spec-jitter-huge", _spec(camera__jitter_px=1e4), "camera.jitter_px")
api_case("own-api-spec-subpixel-3", _spec(appearance__subpixel=3), "subpixel must divide 8")
api_case("own-api-spec-codec", _spec(appearance__video_codec="vp9"), "appearance.video_codec")
api_case("own-api-spec-frames-huge", _spec(frames=10**9), "frames")


def _appearance(**kw):
    def call(w: Path, env: Env):
        from crowdsim.appearance_model import AppearanceParams

        return AppearanceParams(**kw)

    return call


def _encoding(**kw):
    def call(w: Path, env: Env):
        from crowdsim.appearance_model import Encoding

        return Encoding(**kw)

    return call


api_case("own-api-appearance-palette", _appearance(palette="neon"), "appearance.palette")
api_case("own-api-appearance-bgr-2", _appearance(ground_bgr=(1, 2)), "appearance.ground_bgr")
api_case("own-api-appearance-bgr-text", _appearance(ground_bgr="red"), "appearance.ground_bgr")
api_case("own-api-appearance-clusters", _appearance(palette="dark", n_clusters=5), "n_clusters")
api_case("own-api-encoding-jpeg-0", _encoding(jpeg_quality=0), "appearance.jpeg_quality")
api_case("own-api-encoding-kbps-half", _encoding(video_kbps=0.5), "appearance.video_kbps")


# --- the trackers' Python API ---------------------------------------------------------------
def _make(name: str, params=None, **kw):
    def call(w: Path, env: Env):
        from tracker.registry import make_tracker

        return make_tracker(name, params=params, **kw)

    return call


def _direct_init(params):
    def call(w: Path, env: Env):
        from tracker.bqp.tracker import BQPTracker

        BQPTracker(params).init(np.zeros((32, 32, 3), np.uint8), [1], np.array([[9.0, 9.0]]), 8)

    return call


api_case("own-api-make-dict-negative", _make("bqp", {"zeta": -5}), "BQPParams.zeta&&-5")
api_case("own-api-make-dict-unknown", _make("bqp", {"zetaa": 1}), "no parameter(s) zetaa")
api_case("own-api-make-wrong-type", _make("bqp", 3), "takes params as a BQPParams&&int")
api_case(
    "own-api-make-other-params",
    lambda w, env: _make("pnmc", __import__("tracker.bqp.params").bqp.params.BQPParams())(w, env),
    "takes params as a PNMCParams&&BQPParams",
)
api_case("own-api-direct-dict", _direct_init({"zeta": 1}), "takes BQPParams, got dict")
api_case("own-api-search-huge", _make("bqp", search_factor=1e6), "search_factor&&(1, 8]")
api_case("own-api-samples-huge", _make("bqp", n_samples=10**7), "n_samples&&[1, 500]")
api_case("own-api-history-huge", _make("bqp", history=10**8), "history&&[2, 1000]")
api_case("own-api-pnmc-clusters", _make("pnmc", n_clusters=10**6), "n_clusters&&[1, 1000]")
api_case("own-api-ncc-search", _make("ncc", search_factor=100.0), "search_factor&&(1, 8]")
api_case("own-api-meanshift-bins", _make("meanshift", bins=256), "bins&&[2, 32]")
api_case("own-api-unknown-tracker", _make("kalman"), "unknown tracker 'kalman'")


def _step(kind: str):
    def call(w: Path, env: Env):
        from tracker.registry import make_tracker

        tr = make_tracker("ncc")
        frame = np.zeros((32, 32, 3), np.uint8)
        if kind == "before-init":
            tr.step(frame)
        tr.init(frame, [1], np.array([[9.0, 9.0]]), 8)
        if kind == "nan-birth":
            tr.step(frame, births=(np.array([2]), np.array([[np.nan, 3.0]])))
        elif kind == "gray":
            tr.step(np.zeros((32, 32), np.uint8))

    return call


api_case("own-api-step-before-init", _step("before-init"), "init")
api_case("own-api-step-nan-birth", _step("nan-birth"), "birth")
api_case("own-api-step-gray", _step("gray"), "frame")

assert GOOD_CSV  # the shared inputs come from the harness


# --- demo and the table commands never replace a user's file of one of their names ----------
def _users_file(name: str):
    def setup(w: Path, env: Env) -> None:
        p = w / "o" / name
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_text("my own notes\n")

    return setup


DEMO = "demo --out {w}/o --frames 2 --no-progress"
for name in ("summary.json", "results_bqp.txt", "overlay_bqp.mp4"):
    case(
        f"own-demo-user-{name.split('.')[0]}",
        DEMO,
        f"{name} exists and was not written by crowdsim demo",
        setup=_users_file(name),
    )
for command in ("compare", "ablation", "difficulty"):
    for name in ("table.md", "table.csv"):
        case(
            f"own-{command}-user-{name.replace('.', '-')}",
            f"{command} --only seq1 --frames 2 --out {{w}}/o --no-progress",
            f"{name} exists and was not written by a crowdsim table run",
            setup=_users_file(name),
        )
case(
    "own-difficulty-user-attribution",
    "difficulty --only seq1 --frames 2 --out {w}/o --no-progress",
    "attribution.md exists and was not written by a crowdsim table run",
    setup=_users_file("attribution.md"),
)


def _foreign_sequence_folder(w: Path, env: Env) -> None:
    (w / "out" / "tiny").mkdir(parents=True)
    (w / "out" / "tiny" / "notes.txt").write_text("mine\n")


case(
    "own-generate-foreign-folder-advice",
    "generate --spec {spec} --out {w}/out --no-progress",
    "crowdsim cannot replace it&&move it away or choose another --out",
    setup=_foreign_sequence_folder,
)


# --- a file the user names: replaced only when crowdsim wrote it, or with --overwrite ------
MINE = "the file exists and crowdsim cannot prove it wrote it"
TRACK = "track {seq} --tracker ncc --no-progress --frames 2"
NAMED_FILES = (
    ("own-file-track-out", f"{TRACK} --out {{w}}/r.txt", "r.txt", f"r.txt: {MINE}"),
    (
        "own-file-track-video",
        f"{TRACK} --out {{w}}/r.txt --video {{w}}/v.mp4",
        "v.mp4",
        f"--video {{w}}/v.mp4: {MINE}",
    ),
    (
        "own-file-simulate-out",
        "simulate marathon --agents 5 --steps 2 --no-progress --out {w}/t.npz",
        "t.npz",
        f"--out {{w}}/t.npz: {MINE}",
    ),
    (
        "own-file-simulate-plot",
        "simulate marathon --agents 5 --steps 2 --no-progress --plot {w}/t.png",
        "t.png",
        f"--plot {{w}}/t.png: {MINE}",
    ),
    ("own-file-evaluate-plot", "evaluate {res} {seq} --plot {w}/p.png", "p.png", MINE),
    ("own-file-detect-out", "detect {seq} --no-progress --out {w}/h.csv", "h.csv", MINE),
    (
        "own-file-bench-sim-json",
        "bench sim --sizes 10 --peers none --json-out {w}/b.json",
        "b.json",
        f"--json-out {{w}}/b.json: {MINE}",
    ),
    (
        "own-file-bench-envs-json",
        "bench envs --only crowd --agents 10 --steps 2 --json-out {w}/b.json",
        "b.json",
        f"--json-out {{w}}/b.json: {MINE}",
    ),
    ("own-file-bench-fd", "bench fd --densities 1 --out {w}/o", "o/fd.json", f"fd.json: {MINE}"),
    (
        "own-file-bench-solver-plot",
        "bench solver --sizes 10 --out {w}/o",
        "o/solver_convergence.png",
        f"solver_convergence.png: {MINE}",
    ),
    (
        "own-file-bench-solver-npz",
        "bench solver --sizes 10 --no-plot --save-npz {w}/q.npz",
        "q.npz",
        f"--save-npz {{w}}/q.npz: {MINE}",
    ),
)
for cid, argv, name, needle in NAMED_FILES:
    case(cid, argv, needle, files=((name, "the user's own\n"),))


def _track_then_edit(w: Path, env: Env) -> None:
    """``r.txt`` written by ``crowdsim track``, then edited by the user."""
    from crowdsim.cli import main

    argv = [str(env.seq), "--tracker", "ncc", "--no-progress", "--frames", "2"]
    assert main(["track", *argv, "--out", str(w / "r.txt")]) == 0
    with open(w / "r.txt", "a") as fh:
        fh.write("# my note\n")


case("own-file-edited-since", f"{TRACK} --out {{w}}/r.txt", MINE, setup=_track_then_edit)
case(
    "own-file-foreign-ledger",
    f"{TRACK} --out {{w}}/r.txt",
    MINE,
    files=(("r.txt", "mine\n"), (".crowdsim-files.json", '{"files": {"r.txt": "x"}}')),
)
case(
    "own-file-track-out-in-input",
    f"{TRACK} --out {{seq}}/gt/gt.txt --overwrite",
    "would overwrite or sit inside the input INPUT",
)
case(
    "own-file-track-video-is-out",
    f"{TRACK} --out {{w}}/r.mp4 --video {{w}}/r.mp4",
    "--video {w}/r.mp4 would overwrite or sit inside the input --out",
)
case(
    "own-file-track-out-is-init",
    f"{TRACK} --init {{w}}/i.csv --out {{w}}/i.csv --overwrite",
    "--out {w}/i.csv would overwrite or sit inside the input --init",
    files=(("i.csv", GOOD_CSV),),
)
case(
    "own-file-detect-out-is-input",
    "detect {w}/v.csv --no-progress --out {w}/v.csv --overwrite",
    "would overwrite or sit inside the input INPUT",
    files=(("v.csv", "frame,id,x,y\n"),),
)
