"""Generation: deterministic, resumable, atomic, no silent overwrite, local pool and Ray."""

from __future__ import annotations

import argparse
import json
import os
import re
import signal
import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import yaml

from synth_data.generate import generate
from synth_data.mot import read_sequence, sha256_file
from synth_data.spec import spec_from_dict
from synth_data.writer import TMP_PREFIX, read_tmp_marker

ROOT = Path(__file__).resolve().parents[2]


def tiny(name="tiny", seed=4, frames=6, **scenario):
    return spec_from_dict(
        {
            "name": name,
            "seed": seed,
            "frames": frames,
            "warmup_steps": 2,
            "scenario": {"name": "crossing", "n_agents": 12, "density": 1.0, **scenario},
            "camera": {"px_per_m": 10.0, "jitter_px": 0.5},
            "appearance": {"template_px": 8, "noise_sigma": 3.0},
        },
        source=f"{name}.toml",
    )


def frame_bytes(seq_dir: Path) -> list[bytes]:
    return [p.read_bytes() for p in sorted((seq_dir / "img1").glob("*.jpg"))]


def assert_manifest_verified(out: Path, names: list[str]) -> dict:
    manifest = json.loads((out / "manifest.json").read_text())
    assert sorted(manifest["sequences"]) == sorted(names)
    for name, entry in manifest["sequences"].items():
        files = entry["files"]
        on_disk = {
            str(p.relative_to(out / name))
            for p in (out / name).rglob("*")
            if p.is_file() and p.name != "checksums.json"
        }
        assert set(files) == on_disk
        for rel, digest in files.items():
            assert sha256_file(out / name / rel) == digest, rel
    assert not list(out.glob(f"{TMP_PREFIX}*"))
    return manifest


def test_same_spec_and_seed_give_identical_gt_and_frames(tmp_path):
    a = generate([tiny()], tmp_path / "a", progress=False, log=lambda m: None)
    b = generate([tiny()], tmp_path / "b", progress=False, log=lambda m: None)
    assert a["sequences"]["tiny"]["files"] == b["sequences"]["tiny"]["files"]
    ga = (tmp_path / "a/tiny/gt/gt.txt").read_bytes()
    assert ga == (tmp_path / "b/tiny/gt/gt.txt").read_bytes() and len(ga) > 0
    assert frame_bytes(tmp_path / "a/tiny") == frame_bytes(tmp_path / "b/tiny")
    generate([tiny(seed=5)], tmp_path / "c", progress=False, log=lambda m: None)
    assert frame_bytes(tmp_path / "c/tiny") != frame_bytes(tmp_path / "a/tiny")
    seq = read_sequence(tmp_path / "a/tiny")
    assert seq.length == 6 and seq.template_size == 8 and len(list(seq.frames())) == 6
    meta = json.loads((tmp_path / "a/tiny/meta.json").read_text())
    assert meta["seed"] == 4 and meta["spec"]["scenario"]["name"] == "crossing"
    assert "numpy" in meta["versions"]
    agents = seq.agents()
    assert set(agents) == {"id", "group", "prominent", "anomaly", "appearance"}
    assert set(np.unique(seq.gt[:, 1]).astype(int)) == set(agents["id"].tolist())


def test_resume_skips_complete_sequences_and_refuses_to_overwrite(tmp_path):
    out = tmp_path / "out"
    generate([tiny()], out, progress=False, log=lambda m: None)
    first = (out / "tiny/img1/000001.jpg").stat().st_mtime_ns
    logs: list[str] = []
    generate([tiny()], out, progress=False, log=logs.append)
    assert (out / "tiny/img1/000001.jpg").stat().st_mtime_ns == first
    assert any("skipped" in m for m in logs)
    with pytest.raises(FileExistsError, match="different spec.*--overwrite"):
        generate([tiny().truncated(3)], out, progress=False, log=lambda m: None)
    generate([tiny().truncated(3)], out, overwrite=True, progress=False, log=lambda m: None)
    assert read_sequence(out / "tiny").length == 3  # a sequence provably ours is replaced
    assert_manifest_verified(out, ["tiny"])
    (out / "tiny/img1/000002.jpg").write_bytes(b"corrupt")
    with pytest.raises(FileExistsError, match="fails checksum verification"):
        generate([tiny().truncated(3)], out, progress=False, log=lambda m: None)
    # a changed file may be the user's own edit (a blurred face, a corrected gt.txt): even
    # --overwrite refuses, naming it, before anything changes; the user decides
    with pytest.raises(ValueError, match="000002.jpg: damaged"):
        generate([tiny()], out, overwrite=True, progress=False, log=lambda m: None)
    assert (out / "tiny/img1/000002.jpg").read_bytes() == b"corrupt"
    assert "tiny" in json.loads((out / "manifest.json").read_text())["sequences"]


def _cli(argv: list[str]) -> int:
    """``crowdsim <argv>`` through cli.main, or through the command module if the CLI is
    not assembled yet (cli.main maps ValueError/FileExistsError to exit code 2)."""
    from crowdsim import cli

    try:
        return cli.main(argv)
    except ModuleNotFoundError:
        from crowdsim.commands import generate as cmd

        parser = argparse.ArgumentParser()
        cmd.register(parser.add_subparsers(dest="command"))
        args = parser.parse_args(argv)
        try:
            return args.func(args)
        except (ValueError, FileExistsError):
            return 2


def test_cli_truncates_refuses_overwrite_with_exit_2_and_reports_bad_specs(tmp_path, capsys):
    spec = tmp_path / "tiny.toml"
    spec.write_text(
        'name = "tiny"\nseed = 4\nframes = 6\n[scenario]\nname = "crossing"\n'
        "n_agents = 12\ndensity = 1.0\n[appearance]\ntemplate_px = 8\n"
    )
    out = tmp_path / "out"
    assert (
        _cli(["generate", "--spec", str(spec), "--out", str(out), "--frames", "3", "--no-progress"])
        == 0
    )
    assert read_sequence(out / "tiny").length == 3
    assert _cli(["generate", "--spec", str(spec), "--out", str(out), "--no-progress"]) == 2
    assert read_sequence(out / "tiny").length == 3
    bad = tmp_path / "bad.toml"
    bad.write_text(spec.read_text().replace("n_agents = 12", "n_agents = -5"))
    capsys.readouterr()
    assert _cli(["generate", "--spec", str(bad), "--out", str(out), "--no-progress"]) == 2
    assert (
        _cli(
            [
                "generate",
                "--spec",
                str(spec),
                "--out",
                str(out),
                "--backend",
                "local",
                "--address",
                "x:1",
                "--no-progress",
            ]
        )
        == 2
    )


def test_killed_worker_then_rerun_completes_with_right_checksums(tmp_path, slow_jpeg_env):
    specs = []
    for k in (1, 2):
        p = tmp_path / f"s{k}.toml"
        p.write_text(
            f'name = "s{k}"\nseed = {k}\nframes = 200\n[scenario]\nname = "crossing"\n'
            "n_agents = 12\ndensity = 1.0\n[camera]\npx_per_m = 10.0\n"
            "[appearance]\ntemplate_px = 8\n"
        )
        specs += ["--spec", str(p)]
    out = tmp_path / "out"
    cmd = [
        sys.executable,
        "-m",
        "crowdsim",
        "generate",
        "--out",
        str(out),
        "--workers",
        "2",
        "--no-progress",
        *specs,
    ]
    proc = subprocess.Popen(
        cmd, cwd=ROOT, env=slow_jpeg_env, stdout=subprocess.PIPE, stderr=subprocess.PIPE
    )
    victim = None
    try:
        deadline = time.monotonic() + 300  # a hang guard only, as in _busy_writers
        while victim is None and time.monotonic() < deadline and proc.poll() is None:
            for tmp in out.glob(f"{TMP_PREFIX}s*"):
                marker = read_tmp_marker(tmp)
                if marker and len(list((tmp / "img1").glob("*.jpg"))) >= 5:
                    victim = marker["pid"]
                    break
            time.sleep(0.05)
        assert victim is not None and victim != proc.pid, "no worker got mid-sequence"
        os.kill(victim, signal.SIGKILL)
        proc.wait(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 1, proc.stderr.read().decode()
    # Nothing incomplete looks complete: only verified sequences or temporary leftovers.
    for d in out.iterdir():
        if d.is_dir() and not d.name.startswith(TMP_PREFIX):
            assert (d / "checksums.json").is_file()
    rerun = subprocess.run(cmd, cwd=ROOT, env=_env(), capture_output=True, timeout=300)
    assert rerun.returncode == 0, rerun.stderr.decode()
    manifest = assert_manifest_verified(out, ["s1", "s2"])
    assert all(e["frames"] == 200 for e in manifest["sequences"].values())


def test_ray_backend(tmp_path):
    pytest.importorskip(
        "ray",
        reason="Ray is an optional extra, not installed (pip install 'crowdsim[distributed]')",
    )
    manifest = generate(
        [tiny("r1"), tiny("r2", seed=9)],
        tmp_path / "out",
        backend="ray",
        progress=False,
        log=lambda m: None,
    )
    assert_manifest_verified(tmp_path / "out", ["r1", "r2"])
    local = generate([tiny("r1")], tmp_path / "local", progress=False, log=lambda m: None)
    assert manifest["sequences"]["r1"]["files"] == local["sequences"]["r1"]["files"]


def test_ray_missing_is_a_clear_user_error(tmp_path, monkeypatch):
    # Ray is in the dev extra, so hide it: a None entry makes `import ray` raise ImportError.
    monkeypatch.setitem(sys.modules, "ray", None)
    with pytest.raises(ValueError, match=r"--backend ray needs ray.*crowdsim\[distributed\]"):
        generate([tiny()], tmp_path / "out", backend="ray", progress=False, log=lambda m: None)


def test_video_only_output_is_read_back(tmp_path):
    import cv2

    probe = cv2.VideoWriter(
        str(tmp_path / "probe.mp4"), cv2.VideoWriter_fourcc(*"mp4v"), 25.0, (32, 32)
    )
    if not probe.isOpened():
        pytest.skip("this OpenCV build cannot write mp4v")
    probe.release()
    spec = tiny()
    spec = spec_from_dict(
        {**spec.to_dict(), "output": {"images": False, "video": True}}, source="video.toml"
    )
    generate([spec], tmp_path / "out", progress=False, log=lambda m: None)
    seq_dir = tmp_path / "out" / "tiny"
    assert (seq_dir / "video.mp4").is_file() and not (seq_dir / "img1").exists()
    # no image folder, so seqinfo.ini names none (imDir=img1 sent tools looking for one)
    info = (seq_dir / "seqinfo.ini").read_text()
    assert "imDir" not in info and "imExt" not in info and "seqLength=6" in info
    seq = read_sequence(seq_dir)
    frames = list(seq.frames())
    assert len(frames) == seq.length == 6
    assert frames[0].shape == (seq.height, seq.width, 3)
    assert_manifest_verified(tmp_path / "out", ["tiny"])


# ---------------------------------------------------------------------------- reliability
def _spec_files(tmp_path: Path, names: list[str], frames: int) -> list[str]:
    args = []
    for k, name in enumerate(names):
        p = tmp_path / f"{name}.toml"
        p.write_text(
            f'name = "{name}"\nseed = {k + 1}\nframes = {frames}\n[scenario]\n'
            'name = "crossing"\nn_agents = 12\ndensity = 1.0\n[camera]\n'
            "px_per_m = 10.0\n[appearance]\ntemplate_px = 8\n"
        )
        args += ["--spec", str(p)]
    return args


def _gen(out: Path, spec_args: list[str], workers: int) -> list[str]:
    return [
        sys.executable,
        "-m",
        "crowdsim",
        "generate",
        "--out",
        str(out),
        "--workers",
        str(workers),
        "--no-progress",
        *spec_args,
    ]


def _env() -> dict[str, str]:
    return dict(os.environ, PYTHONPATH=str(ROOT))


def _alive(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/status") as fh:
            return "\nState:\tZ" not in fh.read()
    except FileNotFoundError:
        return False


def _busy_writers(out: Path, proc: subprocess.Popen, n: int) -> list[int]:
    """Pids of ``n`` processes each writing a sequence (>= 2 frames on disk)."""
    # a guard against a hang only, not a bound under test: on a loaded 2-core machine the
    # workers took 30 s to write their first frames, and over 60 s once (CI-like load)
    deadline = time.monotonic() + 300
    while time.monotonic() < deadline:
        assert proc.poll() is None, proc.communicate()
        pids = set()
        for tmp in out.glob(f"{TMP_PREFIX}*"):
            marker = read_tmp_marker(tmp)
            if marker and len(list((tmp / "img1").glob("*.jpg"))) >= 2:
                pids.add(marker["pid"])
        if len(pids) >= n:
            return sorted(pids)
        time.sleep(0.05)
    raise AssertionError("the writers did not start")


def test_two_concurrent_runs_into_one_folder_keep_every_manifest_entry(tmp_path):
    out = tmp_path / "out"
    runs = [
        subprocess.Popen(
            _gen(out, _spec_files(tmp_path, [f"{p}{k}" for k in range(4)], 3), 1),
            cwd=ROOT,
            env=_env(),
            stderr=subprocess.PIPE,
        )
        for p in ("a", "b")
    ]
    for r in runs:
        assert r.wait(timeout=120) == 0, r.stderr.read().decode()
    assert_manifest_verified(out, [f"{p}{k}" for p in "ab" for k in range(4)])


def test_a_sequence_another_run_finished_meanwhile_is_taken_not_refused(tmp_path):
    # two runs into one folder (two generates, or a table run beside a generate) that both
    # found seq missing: the one finishing second meets the other's folder at its rename
    from synth_data.generate import build_sequence

    out = tmp_path / "out"
    manifest = generate([tiny()], out, progress=False, log=lambda m: None)
    before = sorted(p.stat().st_mtime_ns for p in (out / "tiny").rglob("*"))
    assert build_sequence(tiny(), out) == manifest["sequences"]["tiny"]
    assert sorted(p.stat().st_mtime_ns for p in (out / "tiny").rglob("*")) == before
    assert not list(out.glob(f"{TMP_PREFIX}*"))
    with pytest.raises(FileExistsError, match="already exists"):  # another spec's: refused
        build_sequence(tiny(seed=5), out)


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
def test_sigkill_of_the_parent_leaves_no_worker_and_a_rerun_completes(tmp_path, slow_jpeg_env):
    out = tmp_path / "out"
    cmd = _gen(out, _spec_files(tmp_path, ["k1", "k2"], 300), 2)
    proc = subprocess.Popen(cmd, cwd=ROOT, env=slow_jpeg_env, stderr=subprocess.PIPE)
    try:
        workers = _busy_writers(out, proc, 2)
        assert proc.pid not in workers
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait(timeout=10)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    deadline = time.monotonic() + 5
    while any(_alive(p) for p in workers) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert not any(_alive(p) for p in workers), "a worker outlived its parent by 5 s"
    left = {p: len(list(p.rglob("*"))) for p in out.glob(f"{TMP_PREFIX}*")}
    time.sleep(0.3)
    assert left and left == {p: len(list(p.rglob("*"))) for p in out.glob(f"{TMP_PREFIX}*")}
    rerun = subprocess.run(cmd, cwd=ROOT, env=_env(), capture_output=True, timeout=300)
    assert rerun.returncode == 0, rerun.stderr.decode()
    assert_manifest_verified(out, ["k1", "k2"])  # leftovers of the killed run are gone


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
@pytest.mark.parametrize(
    "sig, workers", [(signal.SIGINT, min(2, os.cpu_count() or 1)), (signal.SIGTERM, 1)]
)
def test_signal_stops_promptly_removes_temporaries_and_says_so(
    tmp_path, slow_jpeg_env, sig, workers
):
    out = tmp_path / "out"
    cmd = _gen(out, _spec_files(tmp_path, ["i1", "i2", "i3"], 300), workers)
    proc = subprocess.Popen(
        cmd,
        cwd=ROOT,
        env=slow_jpeg_env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        writers = _busy_writers(out, proc, workers)
        t0 = time.monotonic()
        proc.send_signal(sig)
        _, err = proc.communicate(timeout=20)
        elapsed = time.monotonic() - t0
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == {signal.SIGINT: 130, signal.SIGTERM: 143}[sig], err
    *done, last = err.strip().splitlines()
    # on a loaded machine a sequence may finish before the signal lands: it is kept
    assert all(re.fullmatch(r"i\d: 300 frames, .* MB in .* s", line) for line in done), err
    assert elapsed < 5.0
    assert not any(_alive(p) for p in writers if p != proc.pid)
    head = f"crowdsim generate: interrupted by {sig.name}; "
    if done:  # the message says what is kept, and it is
        assert last.startswith(head + "workers stopped") and "kept in" in last, err
        assert all((out / line.split(":")[0]).is_dir() for line in done)
    else:  # nothing finished: the run leaves nothing behind, and says so
        assert last == head + f"nothing was finished; {out} was removed again", err
        assert not out.exists()
        return
    finished = sorted(d.name for d in out.iterdir() if d.is_dir() and d.name[0] != ".")
    assert len(finished) == len(done) < 3  # the signal stopped the work
    assert_manifest_verified(out, finished)  # and no temporary folder is left


def test_cleanup_deletes_only_marked_leftovers_of_dead_processes(tmp_path):
    from synth_data.writer import TMP_MARKER, clean_stale_tmp, make_tmp_dir

    out = tmp_path / "out"
    out.mkdir()
    user = out / ".tmp-notes-2024"  # looks like the old temporary names: a user's folder
    user.mkdir()
    (user / "thesis.txt").write_text("keep me")
    dead = int(
        subprocess.run(
            [sys.executable, "-c", "import os; print(os.getpid())"],
            capture_output=True,
            text=True,
            check=True,
        ).stdout
    )
    unmarked = out / f"{TMP_PREFIX}tiny-{dead}-0123abcd"  # our name, but no marker: keep
    unmarked.mkdir()
    # a writer (render or generate) killed mid-sequence
    killed = subprocess.run(
        [
            sys.executable,
            "-c",
            "import os, signal, sys; from synth_data.writer import "
            "make_tmp_dir; make_tmp_dir(sys.argv[1]); os.kill(os.getpid(), signal.SIGKILL)",
            str(out / "seqA"),
        ],
        env=_env(),
        cwd=ROOT,
    )
    assert killed.returncode == -signal.SIGKILL
    (leftover,) = out.glob(f"{TMP_PREFIX}seqA-*")
    live = make_tmp_dir(out / "live")  # this process is alive
    elsewhere = make_tmp_dir(out / "remote")  # a dead pid, but on another host
    marker = json.loads((elsewhere / TMP_MARKER).read_text())
    (elsewhere / TMP_MARKER).write_text(json.dumps(marker | {"host": "elsewhere", "pid": dead}))
    generate([tiny()], out, progress=False, log=lambda m: None)
    assert (user / "thesis.txt").read_text() == "keep me"
    assert unmarked.is_dir() and live.is_dir() and elsewhere.is_dir()
    assert not leftover.exists()
    assert not (out / "tiny" / TMP_MARKER).exists()
    assert clean_stale_tmp(out) == []
    live.rename(out / f"{TMP_PREFIX}moved")
    assert clean_stale_tmp(tmp_path / "missing") == []


def test_a_failed_run_names_the_folder_and_leaves_nothing(tmp_path, monkeypatch):
    import errno

    import synth_data.generate as gen

    def full_disk(*args, **kwargs):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(gen, "write_sequence", full_disk)
    out = tmp_path / "new" / "out"
    with pytest.raises(OSError, match="No space left on device") as info:
        generate([tiny()], out, progress=False, log=lambda m: None)
    assert info.value.errno == errno.ENOSPC and info.value.filename == str(out)
    assert not out.exists()
    monkeypatch.undo()
    generate([tiny("first")], out, progress=False, log=lambda m: None)
    monkeypatch.setattr(gen, "write_sequence", full_disk)
    with pytest.raises(OSError):
        generate([tiny("second")], out, progress=False, log=lambda m: None)
    assert_manifest_verified(out, ["first"])  # what was finished before stays


@pytest.mark.skipif((os.cpu_count() or 1) < 2, reason="two local workers need two cores")
def test_generation_is_identical_across_processes_and_worker_counts(tmp_path):
    """benchmarks/README.md claims 1- and 2-worker runs identical to the byte: every file of
    every sequence (H.264 and JPEG included) is the same in-process with one worker and in a
    fresh process with two spawned workers."""
    from synth_data.spec import load_spec

    files = []
    for s in (
        tiny("a", seed=1),
        tiny("b", seed=2, n_agents=20),
        replace(tiny("c", seed=3), appearance=replace(tiny().appearance, video_kbps=200.0)),
    ):  # as spec files (YAML is a spec format too): meta.json records the file
        (tmp_path / f"{s.name}.yaml").write_text(yaml.safe_dump(s.to_dict()))
        files += ["--spec", str(tmp_path / f"{s.name}.yaml")]
    specs = [load_spec(f) for f in files[1::2]]
    one = generate(specs, tmp_path / "one", workers=1, progress=False, log=lambda m: None)
    proc = subprocess.run(
        [sys.executable, "-m", "crowdsim", "generate", *files, "--out", str(tmp_path / "two")]
        + ["--workers", "2", "--no-progress"],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert proc.returncode == 0, proc.stderr
    two = json.loads((tmp_path / "two" / "manifest.json").read_text())
    for s in specs:
        a, b = one["sequences"][s.name], two["sequences"][s.name]
        assert a["spec_sha256"] == b["spec_sha256"]
        assert a["files"] == b["files"], s.name
        assert len(a["files"]) >= s.frames + 4
