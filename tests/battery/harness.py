"""The bad-input battery's harness: shared inputs, cases, and how a case is run and judged.

A case is either a command line (:func:`case`: ``crowdsim.cli.main([...])`` in-process) or a
Python call (:func:`api_case`: the library or environment API). Either way it must end the
way a user deserves:

* exit code 2 / the documented exception type (``ValueError``; ``DependencyNotInstalled`` and
  ``gymnasium.error.Error`` subclasses included where the case says so), never another one;
* no ``Traceback`` on stderr, and one line;
* the message names the offending value (a substring given per case, ``&&`` for several);
* no new file or folder anywhere under the case's folder or the shared inputs (nothing
  partial), and every input unchanged (no data loss).

Cases that are not fixed yet carry ``xfail`` with the reason (strict: a fix shows as XPASS).
The case files are ``cases_*.py`` beside this one; ``test_battery.py`` runs them all.
"""

from __future__ import annotations

import contextlib
import io
import os
import shutil
import subprocess
import sys
import time
import traceback
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

# ---------------------------------------------------------------------------- inputs
GOOD_CSV = "frame,id,x,y\n" + "".join(
    f"{t},{i},{1.0 + 0.1 * t + 2 * i:.2f},{1.0 + i:.2f}\n" for t in range(6) for i in (1, 2)
)

SPEC = """\
name = "tiny"
seed = 1
frames = 4
fps = 25.0
warmup_steps = 0

[scenario]
name = "marathon"
n_agents = 6

[camera]
max_width = 96
max_height = 64

[appearance]
template_px = 8
"""


@dataclass
class Env:
    """Shared, read-only inputs of the battery (built once per session)."""

    root: Path
    csv: Path
    npz: Path
    seq: Path
    res: Path
    spec: Path
    afile: Path
    ro: Path | None  # a read-only tmpfs (EROFS), None where mounting is not allowed
    full: Path | None  # a tmpfs with only a few KiB free (ENOSPC)
    mounts: tuple[Path, ...] = ()


def _mount_tmpfs(path: Path, options: str) -> bool:
    path.mkdir(parents=True, exist_ok=True)
    if not sys.platform.startswith("linux") or os.geteuid() != 0 or not shutil.which("mount"):
        return False
    proc = subprocess.run(
        ["mount", "-t", "tmpfs", "-o", options, "tmpfs", str(path)], capture_output=True
    )
    return proc.returncode == 0


def _umount(path: Path) -> None:
    subprocess.run(["umount", "-l", str(path)], capture_output=True)


def write_tiny_sequence(seq: Path, n_frames: int = 6) -> Path:
    """A 64x48 crowdsim-style sequence of two 12 px heads, built without the renderer."""
    import json

    import cv2

    from synth_data.mot import sha256_file, write_mot, write_seqinfo

    (seq / "img1").mkdir(parents=True)
    (seq / "gt").mkdir()
    rows = []
    for t in range(n_frames):
        img = np.full((48, 64, 3), 120, np.uint8)
        for pid, (x, y) in ((1, (10 + 2 * t, 12)), (2, (40, 30 - t))):
            cv2.circle(img, (x, y), 5, (20, 20 * pid, 200), -1)
            rows.append([t + 1, pid, x - 6, y - 6, 12, 12, 1, 1, 1])
        cv2.imwrite(str(seq / "img1" / f"{t + 1:06d}.jpg"), img)
    write_mot(seq / "gt" / "gt.txt", np.array(rows, dtype=np.float64))
    write_seqinfo(
        seq, name="seq", frame_rate=10, length=n_frames, width=64, height=48, template_size=12
    )
    (seq / "meta.json").write_text(json.dumps({"camera": {}, "appearance": {}}) + "\n")
    checks = {
        str(p.relative_to(seq)): sha256_file(p) for p in sorted(seq.rglob("*")) if p.is_file()
    }
    (seq / "checksums.json").write_text(json.dumps(checks) + "\n")
    return seq


def build_env(root: Path) -> Env:
    root.mkdir(parents=True, exist_ok=True)
    csv = root / "walk.csv"
    csv.write_text(GOOD_CSV)
    from crowdsim.trajectories import Trajectories

    npz = Trajectories.from_csv(csv, fps=10).save(root / "walk.npz")
    seq = write_tiny_sequence(root / "seq")
    res = root / "res.txt"
    shutil.copy(seq / "gt" / "gt.txt", res)
    spec = root / "tiny.toml"
    spec.write_text(SPEC)
    afile = root / "afile"
    afile.write_text("a regular file\n")
    mounts = []
    ro: Path | None = root / "ro"
    if _mount_tmpfs(ro, "size=64k,ro"):
        mounts.append(ro)
    else:
        ro = None
    full: Path | None = root / "full"
    if _mount_tmpfs(full, "size=64k"):
        mounts.append(full)
        # Fill it up: new (empty) files and folders can still be made, no byte written.
        with contextlib.suppress(OSError), open(full / "filler", "wb") as fh:
            while True:
                fh.write(b"\0" * 4096)
                fh.flush()
    else:
        full = None
    return Env(root, csv, npz, seq, res, spec, afile, ro, full, tuple(mounts))


# ---------------------------------------------------------------------------- cases
@dataclass(frozen=True)
class Case:
    """One bad input: ``argv`` and ``needle`` may use ``{w}`` (the case's own folder) and
    ``{csv} {npz} {seq} {res} {spec} {afile} {ro} {full} {root}`` (shared inputs)."""

    id: str
    argv: tuple[str, ...]
    needle: str
    files: tuple[tuple[str, str | bytes], ...] = ()  # (relative path in {w}, content)
    setup: Callable[[Path, Env], None] | None = None
    needs: str = ""  # "ro" / "full": skipped where the tmpfs could not be mounted
    xfail: str = ""
    slow: bool = False  # with xfail: not run until fixed (it would take minutes)
    call: Callable[[Path, Env], object] | None = None
    """An API case: ``call(w, env)`` instead of a command line; it must raise one of
    ``raises`` with a one-line message naming ``needle``."""
    raises: tuple[type[BaseException], ...] = (ValueError,)


CASES: list[Case] = []


def api_case(
    id: str,
    call: Callable[[Path, Env], object],
    needle: str,
    raises: tuple[type[BaseException], ...] = (ValueError,),
    **kw,
) -> None:
    """A bad call of the Python API (a library function, a tracker, an environment): it must
    raise one of ``raises`` (never another exception, never return) naming ``needle``."""
    CASES.append(Case(id, (), needle, call=call, raises=raises, **kw))


def case(id: str, argv: str | list[str], needle: str, **kw) -> None:
    args = tuple(argv.split()) if isinstance(argv, str) else tuple(argv)
    CASES.append(Case(id, args, needle, **kw))


def _fmt(text: str, w: Path, env: Env) -> str:
    return text.format(
        w=w,
        csv=env.csv,
        npz=env.npz,
        seq=env.seq,
        res=env.res,
        spec=env.spec,
        afile=env.afile,
        ro=env.ro,
        full=env.full,
        root=env.root,
    )


def seq_copy(edit: Callable[[Path], None], keep_checksums: bool) -> Callable[[Path, Env], None]:
    """A damaged copy of the shared sequence; without ``checksums.json`` (like a real MOT
    sequence) unless ``keep_checksums``."""

    def setup(w: Path, env: Env) -> None:
        shutil.copytree(env.seq, w / "s")
        if not keep_checksums:
            (w / "s" / "checksums.json").unlink()
        edit(w / "s")

    return setup


def _ini(key: str, value: str) -> Callable[[Path], None]:
    def edit(s: Path) -> None:
        lines = (s / "seqinfo.ini").read_text().splitlines()
        lines = [f"{key}={value}" if ln.startswith(f"{key}=") else ln for ln in lines]
        if not any(ln.startswith(f"{key}=") for ln in lines):
            lines.append(f"{key}={value}")
        (s / "seqinfo.ini").write_text("\n".join(lines) + "\n")

    return edit


def _gt(text: str) -> Callable[[Path], None]:
    def edit(s: Path) -> None:
        (s / "gt" / "gt.txt").write_text(text)

    return edit


def _append_gt(text: str) -> Callable[[Path], None]:
    def edit(s: Path) -> None:
        with open(s / "gt" / "gt.txt", "a") as fh:
            fh.write(text)

    return edit


def _truncate_jpeg(s: Path) -> None:
    p = s / "img1" / "000003.jpg"
    p.write_bytes(p.read_bytes()[: len(p.read_bytes()) // 2])


# ---------------------------------------------------------------------------- running
def _snapshot(*roots: Path) -> dict[str, tuple[int, int] | None]:
    out: dict[str, tuple[int, int] | None] = {}
    for root in roots:
        for dirpath, dirnames, filenames in os.walk(root):
            d = Path(dirpath)
            for name in dirnames:
                out[str(d / name)] = None
            for name in filenames:
                p = d / name
                try:
                    st = p.lstat()
                except OSError:
                    continue
                out[str(p)] = (st.st_size, st.st_mtime_ns)
    return out


def names(err: str, needle: str) -> bool:
    """All ``&&``-separated parts of ``needle`` occur in ``err``."""
    return all(part in err for part in needle.split("&&"))


@dataclass
class Outcome:
    rc: int | None
    err: str
    new: list[str]  # files or folders that appeared
    lost: list[str]  # inputs changed or removed

    def kind(self, needle: str) -> str:
        if "Traceback" in self.err or self.rc is None:
            return "traceback"
        if self.lost:
            return "data loss"
        if self.rc == 0:
            return "silent"
        lines = [ln for ln in self.err.strip().splitlines() if ln.strip()]
        named = names(self.err, needle) and self.rc == 2 and not self.new
        one_line = len(lines) == 1 or (lines and lines[0].startswith("usage:"))
        return "clear" if named and one_line else "unclear"


def run_case(c: Case, env: Env, work: Path) -> Outcome:
    from crowdsim.cli import main

    work.mkdir(parents=True, exist_ok=True)
    for rel, content in c.files:
        p = work / rel
        p.parent.mkdir(parents=True, exist_ok=True)
        (p.write_bytes if isinstance(content, bytes) else p.write_text)(content)
    if c.setup is not None:
        c.setup(work, env)
    argv = [_fmt(a, work, env) for a in c.argv]
    before = _snapshot(env.root)
    err = io.StringIO()
    rc: int | None
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        try:
            if c.call is not None:
                try:
                    c.call(work, env)
                    rc = 0
                except c.raises as exc:  # the documented error: one line, like the CLI's
                    print(f"{type(exc).__name__}: {exc}", file=sys.stderr)
                    rc = 2
            else:
                rc = main(argv)
        except SystemExit as exc:  # argparse usage errors
            rc = exc.code if isinstance(exc.code, int) else 2
        except BaseException:  # noqa: BLE001 - the battery records every escape
            traceback.print_exc(file=err)
            rc = None
    after = _snapshot(env.root)
    new = sorted(set(after) - set(before))
    lost = sorted(k for k, v in before.items() if k not in after or after[k] != v)
    return Outcome(rc, err.getvalue(), new, lost)


def load_cases() -> list[Case]:
    """Import every ``cases_*.py`` beside this module (each registers its cases); all cases."""
    import importlib

    for path in sorted(Path(__file__).parent.glob("cases_*.py")):
        importlib.import_module(f"battery.{path.stem}")
    return CASES


def summary(root: Path, run_slow: bool = False) -> dict[str, int]:
    """Run every case and count the outcomes (for the closing notes)."""
    load_cases()
    env = build_env(root)
    counts = {
        "tried": 0,
        "clear": 0,
        "traceback": 0,
        "silent": 0,
        "data loss": 0,
        "unclear": 0,
        "skipped": 0,
    }
    try:
        for c in CASES:
            if (c.needs and getattr(env, c.needs) is None) or (c.slow and not run_slow):
                counts["skipped"] += 1
                continue
            work = env.root / "cases" / c.id
            t0 = time.perf_counter()
            o = run_case(c, env, work)
            took = time.perf_counter() - t0
            if took > 2:
                print(f"slow       {c.id:<34} {took:.1f} s", file=sys.stderr)
            kind = o.kind(_fmt(c.needle, work, env))
            counts["tried"] += 1
            counts[kind] += 1
            if kind == "clear" and c.xfail:
                print(f"XPASS      {c.id:<34} (unmark: {c.xfail})", file=sys.stderr)
            if kind != "clear":
                first = (o.err.strip().splitlines() or [""])[-1][:150]
                print(f"{kind:<10} {c.id:<34} rc={o.rc} {first}", file=sys.stderr)
    finally:
        for m in env.mounts:
            _umount(m)
    return counts
