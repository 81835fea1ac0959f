"""The episode cache: every episode rendered and encoded once, checksummed on disk, read back
by resets, epochs and processes with the very frames and ground truth of a fresh rendering;
a damaged entry is moved aside and rendered again, never trusted."""

from __future__ import annotations

import hashlib
import io
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import envs.episodes as episodes
from envs.episodes import (
    DAMAGED_DIR,
    EpisodeCache,
    ScenarioDistribution,
    ScenarioEpisodes,
    _Cache,
    episode_key,
    make_episodes,
    spec_sequence,
    tiny_scenarios,
)
from envs.tracker_tuning import TrackerTuningEnv

TINY = ScenarioDistribution.from_dict(tiny_scenarios())


def _same_episode(a, b) -> None:
    assert (a.name, a.length, a.width, a.height) == (b.name, b.length, b.width, b.height)
    assert a.template_size == b.template_size and a.frame_rate == b.frame_rate
    fa, fb = list(a.frames()), list(b.frames())
    assert len(fa) == len(fb) == a.length
    for x, y in zip(fa, fb, strict=True):
        assert x.dtype == y.dtype == np.uint8 and np.array_equal(x, y)
    (ia, pa), (ib, pb) = a.gt_points(), b.gt_points()
    assert np.array_equal(ia, ib) and np.array_equal(pa, pb, equal_nan=True)
    (ia0, pa0), births_a = a.births()
    (ib0, pb0), births_b = b.births()
    assert np.array_equal(ia0, ib0) and np.array_equal(pa0, pb0)
    assert births_a.keys() == births_b.keys()


def _entries(root: Path) -> list[Path]:
    return sorted(p for p in root.iterdir() if p.is_dir() and p.name != DAMAGED_DIR)


def test_a_cached_episode_is_the_rendered_one_and_is_stored_once(tmp_path):
    cache = EpisodeCache(tmp_path / "cache")
    spec = ScenarioEpisodes(TINY).spec(3)
    first = cache.sequence(spec)  # rendered, encoded and stored
    again = cache.sequence(spec)  # read back
    assert (cache.stores, cache.hits) == (1, 1)
    fresh = spec_sequence(spec)
    _same_episode(first, fresh)
    _same_episode(again, fresh)
    (entry,) = _entries(tmp_path / "cache")
    assert entry.name == episode_key(spec)
    meta = json.loads((entry / "episode.json").read_text())
    assert meta["format"] == "crowdsim-episode" and meta["spec"] == spec.to_dict()
    assert sorted(p.name for p in entry.iterdir()) == ["episode.json", "frames.bin", "truth.npz"]
    # a new process (another key computation, the same code) reads the same entry
    code = (
        "import sys; from envs.episodes import EpisodeCache, ScenarioEpisodes, "
        "ScenarioDistribution, tiny_scenarios\n"
        "c = EpisodeCache(sys.argv[1]); "
        "s = ScenarioEpisodes(ScenarioDistribution.from_dict(tiny_scenarios())).spec(3)\n"
        "c.sequence(s); print(c.hits, c.stores)"
    )
    out = subprocess.run(
        [sys.executable, "-c", code, str(tmp_path / "cache")],
        capture_output=True,
        text=True,
        check=True,
    )
    assert out.stdout.split() == ["1", "0"]


def test_keys_follow_what_changes_the_frames():
    src = ScenarioEpisodes(TINY)
    a, b = src.spec(0), src.spec(1)
    assert episode_key(a) == episode_key(src.spec(0))
    assert episode_key(a) != episode_key(b)
    from dataclasses import replace

    assert episode_key(replace(a, seed=a.seed + 1)) != episode_key(a)
    assert episode_key(replace(a, description="another text")) == episode_key(a)


def _damage_frames(entry: Path) -> None:
    blob = bytearray((entry / "frames.bin").read_bytes())
    blob[len(blob) // 2] ^= 0xFF
    (entry / "frames.bin").write_bytes(bytes(blob))


def _damage_meta(entry: Path) -> None:
    (entry / "episode.json").write_text("{not json")


def _drop_truth(entry: Path) -> None:
    (entry / "truth.npz").unlink()


def _foreign_checksums(entry: Path) -> None:
    meta = json.loads((entry / "episode.json").read_text())
    meta["sha256"]["truth.npz"] = "0" * 64
    (entry / "episode.json").write_text(json.dumps(meta))


@pytest.mark.parametrize(
    "damage, reason",
    [
        (_damage_frames, "frames.bin: checksum mismatch"),
        (_damage_meta, "unreadable"),
        (_drop_truth, "unreadable"),
        (_foreign_checksums, "truth.npz: checksum mismatch"),
    ],
)
def test_a_damaged_entry_is_moved_aside_and_rendered_again(tmp_path, damage, reason):
    logs: list[str] = []
    root = tmp_path / "cache"
    spec = ScenarioEpisodes(TINY).spec(1)
    EpisodeCache(root).sequence(spec)
    (entry,) = _entries(root)
    damage(entry)
    kept = sorted(p.name for p in entry.iterdir())
    cache = EpisodeCache(root, log=logs.append)
    seq = cache.sequence(spec)
    assert (cache.damaged, cache.hits, cache.stores) == (1, 0, 1)
    _same_episode(seq, spec_sequence(spec))
    (moved,) = (root / DAMAGED_DIR).iterdir()  # never deleted
    assert sorted(p.name for p in moved.iterdir()) == kept
    assert len(logs) == 1 and reason in logs[0] and str(entry) in logs[0]
    assert EpisodeCache(root).load(spec) is not None  # the new entry is sound


def test_a_failed_store_leaves_nothing_and_a_lost_race_keeps_one_entry(tmp_path, monkeypatch):
    root = tmp_path / "cache"
    spec = ScenarioEpisodes(TINY).spec(2)
    cache = EpisodeCache(root)
    real = Path.write_bytes

    def full_disk(self, data):
        if self.name == "truth.npz":  # the second file of the entry
            raise OSError(28, "No space left on device")
        return real(self, data)

    monkeypatch.setattr(Path, "write_bytes", full_disk)
    with pytest.raises(OSError, match="No space left"):
        cache.store(spec)
    monkeypatch.setattr(Path, "write_bytes", real)
    assert list(root.iterdir()) == []  # no entry, no temporary folder
    cache.store(spec)
    cache.store(spec)  # a second process storing the same episode: one entry stays
    assert [p.name for p in root.iterdir()] == [episode_key(spec)]


def test_the_cache_refuses_a_file_and_a_pool_is_required_with_scenarios(tmp_path):
    f = tmp_path / "file"
    f.write_text("mine")
    with pytest.raises(ValueError, match="not a folder"):
        EpisodeCache(f)
    assert f.read_text() == "mine"
    with pytest.raises(ValueError, match="pool=N"):
        make_episodes(scenarios=TINY, episode_cache=tmp_path / "c")
    with pytest.raises(ValueError, match="pool"):
        make_episodes(scenarios=TINY, pool=0)
    with pytest.raises(ValueError, match="--pool draws from a scenario"):
        make_episodes(suite="ucf9", pool=3)


def test_fill_stores_the_pool_over_processes_and_then_finds_it(tmp_path):
    root = tmp_path / "cache"
    (root / "notes.txt").parent.mkdir()
    (root / "notes.txt").write_text("a user's file")
    src = make_episodes(scenarios=TINY, episode_cache=root, pool=3)
    done = src.fill(workers=2, progress=False)
    assert (done["episodes"], done["stored"], done["present"]) == (3, 3, 0)
    assert src.fill(progress=False)["present"] == 3
    assert len(_entries(root)) == 3 and (root / "notes.txt").read_text() == "a user's file"
    assert not [p for p in root.iterdir() if p.name.startswith(".tmp-")]
    assert make_episodes(scenarios=TINY).fill() is None  # no cache, nothing to fill


def test_env_with_the_cache_tracks_exactly_as_without(tmp_path):
    kw = {"scenarios": tiny_scenarios(), "k_frames": 4, "pool": 2}
    plain = TrackerTuningEnv(**kw)
    cached = TrackerTuningEnv(**kw, episode_cache=str(tmp_path / "cache"))
    rng = np.random.default_rng(0)
    for epoch in range(2):
        for env in (plain, cached):
            env.reset(seed=epoch)
        done = False
        while not done:
            a = rng.uniform(-1, 1, plain.action_space.shape).astype(np.float32)
            o1, r1, done, _, i1 = plain.step(a)
            o2, r2, d2, _, i2 = cached.step(a)
            assert np.array_equal(o1, o2) and r1 == r2 and done == d2
            assert i1["sequence"] == i2["sequence"]
    store = cached.episodes.store
    assert store.stores + store.hits == 2 and store.stores <= 2  # rendered once each at most


def test_train_fills_the_cache_first(tmp_path):
    pytest.importorskip("stable_baselines3")
    from envs.training import train

    doc = train(
        "ppo",
        out=tmp_path / "run",
        steps=4,
        env_kwargs={
            "scenarios": tiny_scenarios(),
            "k_frames": 6,
            "episode_cache": str(tmp_path / "cache"),
            "pool": 2,
        },
        progress=False,
        log=lambda m: None,
    )
    assert doc["episode_cache"]["stored"] == 2
    assert len(_entries(tmp_path / "cache")) == 2


@pytest.mark.parametrize(
    "argv, needle",
    [
        (["--pool", "4"], "--pool needs --episode-cache DIR"),
        (["--episode-cache", "C", "--pool", "0"], "--pool must be an integer >= 1, got 0"),
        (["--suite", "ucf9", "--episode-cache", "C", "--pool", "2"], "a --suite has its own"),
    ],
)
def test_train_cache_flags_are_checked(tmp_path, monkeypatch, capsys, argv, needle):
    from crowdsim.cli import main

    monkeypatch.chdir(tmp_path)
    assert main(["train", "--algo", "ppo", "--out", "o", *argv]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and needle in err and "Traceback" not in err
    assert sorted(p.name for p in tmp_path.iterdir()) == []


def test_episode_key_changes_with_the_code_digest(monkeypatch):
    """The key is sha256 of (format, version, spec digest, code digest): other code, another key."""
    spec = ScenarioEpisodes(TINY).spec(0)
    key = episode_key(spec)
    doc = ["crowdsim-episode", 1, spec.digest(), episodes.code_digest()]
    assert key == hashlib.sha256(json.dumps(doc).encode()).hexdigest()[:40]
    monkeypatch.setattr(episodes, "code_digest", lambda: "0" * 64)
    assert episode_key(spec) != key


def test_in_memory_episode_cache_evicts_the_least_recently_used():
    """_Cache is an LRU: a hit refreshes an entry, so the next insertion evicts the other one."""
    built: list[str] = []
    cache = _Cache(2)

    def get(key):
        return cache.get(key, lambda: built.append(key) or key.upper())

    assert [get("a"), get("b"), get("a"), get("c")] == ["A", "B", "A", "C"]
    assert built == ["a", "b", "c"]
    get("a")  # still there
    assert built == ["a", "b", "c"]
    get("b")  # evicted by c
    assert built == ["a", "b", "c", "b"]


def test_an_entry_with_an_empty_frame_is_damaged(tmp_path):
    """A zero-length frame (with consistent checksums) is a damaged entry, not loaded."""
    spec = ScenarioEpisodes(TINY).spec(1)
    root = tmp_path / "cache"
    EpisodeCache(root).sequence(spec)
    entry = EpisodeCache(root).entry(spec)
    with np.load(entry / "truth.npz") as z:
        truth = {k: z[k].copy() for k in z.files}
    truth["offsets"][1] = truth["offsets"][0]  # frame 0 has no bytes
    buf = io.BytesIO()
    np.savez(buf, **truth)
    (entry / "truth.npz").write_bytes(buf.getvalue())
    meta = json.loads((entry / "episode.json").read_text())
    meta["sha256"]["truth.npz"] = hashlib.sha256(buf.getvalue()).hexdigest()
    (entry / "episode.json").write_text(json.dumps(meta))
    logs: list[str] = []
    cache = EpisodeCache(root, log=logs.append)
    assert cache.load(spec) is None
    assert cache.damaged == 1 and "inconsistent" in logs[0]


def test_the_code_digest_covers_the_numba_scipy_and_pyav_versions(monkeypatch):
    """Another numba (force kernels), SciPy (spawn trees) or PyAV (libx264's H.264 bytes)
    makes other frames, so it must make another key."""
    from importlib import metadata

    real = metadata.version
    digest = episodes.code_digest.__wrapped__
    before = digest()
    for dist in ("numba", "scipy", "av"):
        monkeypatch.setattr(
            metadata, "version", lambda name, d=dist: "0.0.0-other" if name == d else real(name)
        )
        assert digest() != before, dist
    monkeypatch.setattr(metadata, "version", real)
    assert digest() == before
