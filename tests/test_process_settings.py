"""The process-wide settings the ``crowdsim`` command applies (crowdsim.cli.process_settings)."""

from __future__ import annotations

import platform

import pytest

from crowdsim.cli import KEEP_FREED, process_settings

GLIBC = platform.system() == "Linux" and platform.libc_ver()[0] == "glibc"


@pytest.fixture
def clean_env(monkeypatch):
    for name in (*KEEP_FREED, "OMP_WAIT_POLICY", "GLIBC_TUNABLES"):
        monkeypatch.delenv(name, raising=False)
    return monkeypatch


MAPPED = """
import ctypes, numpy as np
names = "arena ordblks smblks hblks hblkhd usmblks fsmblks uordblks fordblks keepcost"
class Info(ctypes.Structure):
    _fields_ = [(n, ctypes.c_size_t) for n in names.split()]
info = ctypes.CDLL(None).mallinfo2
info.restype = Info
before = info().hblkhd
a = np.ones(8 << 20)  # 64 MB
print(info().hblkhd - before)
"""
"""Prints how many bytes malloc took with a fresh ``mmap`` for one live 64 MB array."""


def _mapped(env) -> int:
    import subprocess
    import sys

    run = subprocess.run([sys.executable, "-c", MAPPED], env=env, capture_output=True, text=True)
    if run.returncode != 0 and "mallinfo2" in run.stderr:
        pytest.skip("glibc older than 2.33 (no mallinfo2)")
    return int(run.stdout)


@pytest.mark.skipif(not GLIBC, reason="glibc's malloc only")
def test_malloc_keeps_large_blocks_on_the_heap_here_and_in_child_processes(clean_env):
    import os

    plain = {k: v for k, v in os.environ.items() if k not in KEEP_FREED}
    assert _mapped(plain) >= 64 << 20  # glibc's default: a block of its own, unmapped on free
    process_settings()
    assert os.environ["OMP_WAIT_POLICY"] == "PASSIVE"
    assert {k: int(os.environ[k]) for k in KEEP_FREED} == KEEP_FREED
    assert _mapped(dict(os.environ)) < 1 << 20  # a child: from the heap, kept when freed
    namespace: dict = {}
    exec(MAPPED.replace("print(", "result = ("), namespace)  # this process, through mallopt
    assert namespace["result"] < 1 << 20


@pytest.mark.parametrize(
    "users", [{"MALLOC_TRIM_THRESHOLD_": "0"}, {"GLIBC_TUNABLES": "glibc.malloc.arena_max=1"}]
)
def test_a_users_malloc_setting_wins(clean_env, users):
    import os

    for name, value in users.items():
        clean_env.setenv(name, value)
    clean_env.setenv("OMP_WAIT_POLICY", "ACTIVE")
    process_settings()
    assert os.environ["OMP_WAIT_POLICY"] == "ACTIVE"
    for name in KEEP_FREED:
        assert os.environ.get(name) == users.get(name)
