"""Generation: deterministic, resumable, atomic, no silent overwrite, local pool and Ray."""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from synth_data.generate import generate
from synth_data.mot import read_sequence
from synth_data.spec import spec_from_dict
from synth_data.writer import TMP_PREFIX, sha256_file

ROOT = Path(__file__).resolve().parents[2]


def tiny(name="tiny", seed=4, frames=6, **scenario):
    return spec_from_dict({
        "name": name, "seed": seed, "frames": frames, "warmup_steps": 2,
        "scenario": {"name": "crossing", "n_agents": 12, "density": 1.0, **scenario},
        "camera": {"px_per_m": 10.0, "jitter_px": 0.5},
        "appearance": {"template_px": 8, "noise_sigma": 3.0},
    }, source=f"{name}.toml")


def frame_bytes(seq_dir: Path) -> list[bytes]:
    return [p.read_bytes() for p in sorted((seq_dir / "img1").glob("*.jpg"))]


def assert_manifest_verified(out: Path, names: list[str]) -> dict:
    manifest = json.loads((out / "manifest.json").read_text())
    assert sorted(manifest["sequences"]) == sorted(names)
    for name, entry in manifest["sequences"].items():
        files = entry["files"]
        on_disk = {str(p.relative_to(out / name)) for p in (out / name).rglob("*")
                   if p.is_file() and p.name != "checksums.json"}
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
    (out / "tiny/img1/000002.jpg").write_bytes(b"corrupt")
    with pytest.raises(FileExistsError, match="fails checksum verification"):
        generate([tiny()], out, progress=False, log=lambda m: None)
    generate([tiny().truncated(3)], out, overwrite=True, progress=False, log=lambda m: None)
    assert read_sequence(out / "tiny").length == 3
    assert_manifest_verified(out, ["tiny"])


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
    spec.write_text('name = "tiny"\nseed = 4\nframes = 6\n[scenario]\nname = "crossing"\n'
                    'n_agents = 12\ndensity = 1.0\n[appearance]\ntemplate_px = 8\n')
    out = tmp_path / "out"
    assert _cli(["generate", "--spec", str(spec), "--out", str(out), "--frames", "3",
                 "--no-progress"]) == 0
    assert read_sequence(out / "tiny").length == 3
    assert _cli(["generate", "--spec", str(spec), "--out", str(out), "--no-progress"]) == 2
    assert read_sequence(out / "tiny").length == 3
    bad = tmp_path / "bad.toml"
    bad.write_text(spec.read_text().replace("n_agents = 12", "n_agents = -5"))
    capsys.readouterr()
    assert _cli(["generate", "--spec", str(bad), "--out", str(out), "--no-progress"]) == 2
    assert _cli(["generate", "--spec", str(spec), "--out", str(out), "--backend", "local",
                 "--address", "x:1", "--no-progress"]) == 2


def test_killed_worker_then_rerun_completes_with_right_checksums(tmp_path):
    specs = []
    for k in (1, 2):
        p = tmp_path / f"s{k}.toml"
        p.write_text(f'name = "s{k}"\nseed = {k}\nframes = 400\n[scenario]\nname = "crossing"\n'
                     'n_agents = 12\ndensity = 1.0\n[camera]\npx_per_m = 10.0\n'
                     '[appearance]\ntemplate_px = 8\n')
        specs += ["--spec", str(p)]
    out = tmp_path / "out"
    cmd = [sys.executable, "-m", "crowdsim.commands._generate_main", "--out", str(out),
           "--workers", "2", "--no-progress", *specs]
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    proc = subprocess.Popen(cmd, cwd=ROOT, env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE)
    victim = None
    try:
        deadline = time.monotonic() + 120
        while victim is None and time.monotonic() < deadline and proc.poll() is None:
            for tmp in out.glob(f"{TMP_PREFIX}s*"):
                if len(list((tmp / "img1").glob("*.jpg"))) >= 5:
                    victim = int(tmp.name.rsplit("-", 1)[1])
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
    rerun = subprocess.run(cmd, cwd=ROOT, env=env, capture_output=True, timeout=300)
    assert rerun.returncode == 0, rerun.stderr.decode()
    manifest = assert_manifest_verified(out, ["s1", "s2"])
    assert all(e["frames"] == 400 for e in manifest["sequences"].values())


def test_ray_backend(tmp_path):
    pytest.importorskip("ray", reason="Ray is an optional extra, not installed "
                                      "(pip install 'crowdsim[distributed]')")
    manifest = generate([tiny("r1"), tiny("r2", seed=9)], tmp_path / "out", backend="ray",
                        progress=False, log=lambda m: None)
    assert_manifest_verified(tmp_path / "out", ["r1", "r2"])
    local = generate([tiny("r1")], tmp_path / "local", progress=False, log=lambda m: None)
    assert manifest["sequences"]["r1"]["files"] == local["sequences"]["r1"]["files"]


def test_ray_missing_is_a_clear_user_error(tmp_path):
    try:
        import ray  # noqa: F401
    except ImportError:
        pass
    else:
        pytest.skip("Ray is installed; the missing-Ray message cannot be shown")
    with pytest.raises(ValueError, match=r"--backend ray needs Ray.*crowdsim\[distributed\]"):
        generate([tiny()], tmp_path / "out", backend="ray", progress=False, log=lambda m: None)


def test_video_only_output_is_read_back(tmp_path):
    import cv2

    probe = cv2.VideoWriter(str(tmp_path / "probe.mp4"), cv2.VideoWriter_fourcc(*"mp4v"), 25.0,
                            (32, 32))
    if not probe.isOpened():
        pytest.skip("this OpenCV build cannot write mp4v")
    probe.release()
    spec = tiny()
    spec = spec_from_dict({**spec.to_dict(), "output": {"images": False, "video": True}},
                          source="video.toml")
    generate([spec], tmp_path / "out", progress=False, log=lambda m: None)
    seq_dir = tmp_path / "out" / "tiny"
    assert (seq_dir / "video.mp4").is_file() and not (seq_dir / "img1").exists()
    seq = read_sequence(seq_dir)
    frames = list(seq.frames())
    assert len(frames) == seq.length == 6
    assert frames[0].shape == (seq.height, seq.width, 3)
    assert_manifest_verified(tmp_path / "out", ["tiny"])
