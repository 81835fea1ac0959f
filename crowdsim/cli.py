"""The ``crowdsim`` console command.

Each sub-command lives in its own module under :mod:`crowdsim.commands` and exposes
``register(subparsers)``; the module adds its parser and sets ``func`` to a callable taking the
parsed arguments and returning an exit code. Heavy imports happen inside ``func`` so that
``crowdsim --help`` stays fast.

User errors (bad flags, bad files, out-of-range parameters) end with exit code 2 and one line
``crowdsim <command>: error: <message>`` on stderr, never a traceback. SIGINT (Ctrl-C) ends any
command with exit code 130 and SIGTERM with 143, after the command's clean-ups ran, with one
line ``crowdsim <command>: interrupted by SIGINT|SIGTERM[; what was removed or kept]`` (see
:func:`main`).
"""

from __future__ import annotations

import argparse
import os
import sys
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from types import ModuleType

from crowdsim import __version__
from crowdsim.atomic import describe_os_error
from crowdsim.checks import refuse_empty_paths
from crowdsim.commands import (
    ablation,
    bench,
    calibrate,
    compare,
    demo,
    detect,
    detector,
    difficulty,
    evaluate,
    generate,
    headroom,
    heldout,
    render,
    simulate,
    track,
    train,
    tune,
)
from crowdsim.jobs import EXIT_CODES, interrupt_in, interruptible

COMMANDS: tuple[ModuleType, ...] = (
    simulate,
    track,
    detect,
    evaluate,
    render,
    generate,
    calibrate,
    compare,
    ablation,
    difficulty,
    tune,
    train,
    heldout,
    headroom,
    detector,
    bench,
    demo,
)
"""Modules that register a sub-command, in the order ``--help`` lists them (each imports only
the standard library at import; its work imports what it needs when it runs)."""


class UsageError(ValueError):
    """A user error found after argument parsing (bad file, bad combination of flags)."""


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="crowdsim",
        description="Dense-crowd tracking testbed: simulate crowds, render synthetic "
        "benchmarks, track and evaluate.",
    )
    parser.add_argument("--version", action="version", version=f"crowdsim {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    for command in COMMANDS:
        command.register(sub)
    return parser


def _command_parser(
    parser: argparse.ArgumentParser, args: argparse.Namespace
) -> argparse.ArgumentParser:
    """The (sub-)sub-parser of the command ``args`` holds (``detector train``), or ``parser``."""
    for name in (args.command, getattr(args, "verb", None)):
        subs = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
        if name is None or not subs or name not in subs[0].choices:
            break
        parser = subs[0].choices[name]
    return parser


KEEP_FREED: dict[str, int] = {
    "MALLOC_MMAP_THRESHOLD_": 128 << 20,
    "MALLOC_TRIM_THRESHOLD_": 256 << 20,
}
"""glibc's malloc settings :func:`process_settings` asks for: blocks up to 128 MB from the
heap (not a fresh ``mmap`` each), and up to 256 MB of freed heap kept (not given back)."""


def process_settings() -> None:
    """The process-wide settings the application owns (library modules set none). Each is
    left alone when the user set it.

    * ``OMP_WAIT_POLICY=PASSIVE``: numba's OpenMP layer busy-waits between parallel regions
      by default, which on a shared 2-core machine steals the cores from the other thread
      (rendering 1280x720 with 1k agents under load: 59 frames/s spinning, 151 passive).
    * glibc's malloc keeps freed blocks (:data:`KEEP_FREED`; for child processes through the
      environment, which glibc reads at start, and for this one through ``mallopt``). By
      default glibc hands every freed block over 32 MB back to the system and trims its
      heap. A tracker at thousands of targets makes some 200 MB of such temporaries a frame,
      and the kernel zeroed and mapped them in again every frame: at 7,850 targets 60-70 ms
      of system time a frame, 9,000-11,000 page faults. With the blocks kept: 0-150 faults,
      2-7 ms, and stress-10k at 6.4-6.6 frames/s against 4.2-4.8 (same tracks). Other C
      libraries are left as they are.
    """
    os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
    tunables = os.environ.get("GLIBC_TUNABLES", "")
    if any(k in os.environ for k in KEEP_FREED) or "glibc.malloc." in tunables:
        return
    import platform

    if platform.system() != "Linux" or platform.libc_ver()[0] != "glibc":
        return
    import ctypes

    try:
        mallopt = ctypes.CDLL(None).mallopt
    except (OSError, AttributeError):
        return
    m_trim_threshold, m_mmap_threshold = -1, -3  # <malloc.h>
    # both, or neither: a trim threshold alone turns off the adaptive mmap threshold
    if mallopt(m_mmap_threshold, KEEP_FREED["MALLOC_MMAP_THRESHOLD_"]) and mallopt(
        m_trim_threshold, KEEP_FREED["MALLOC_TRIM_THRESHOLD_"]
    ):
        os.environ.update({k: str(v) for k, v in KEEP_FREED.items()})


@contextmanager
def _notes_as_lines(command: str) -> Iterator[None]:
    """Print each :class:`crowdsim.checks.DataNote` warning as one line ``crowdsim <command>:
    note: <message>`` while the command runs (other warnings as Python prints them)."""
    import warnings

    from crowdsim.checks import DataNote, note_line

    shown = warnings.showwarning

    def show(message, category, filename, lineno, file=None, line=None):  # noqa: ANN001
        if issubclass(category, DataNote):
            print(note_line(command, message), file=sys.stderr)
        else:
            shown(message, category, filename, lineno, file, line)

    warnings.showwarning = show
    try:
        yield
    finally:
        warnings.showwarning = shown


def main(argv: Sequence[str] | None = None) -> int:
    """Run one sub-command; returns its exit code.

    Exit codes, the same for every command: 0 done; 1 the work itself failed (a job of a job
    runner raised or its worker died: generate, compare, tune, ...); 2 a user error or a
    file-system error, and a simulator strip worker that died (simulate writes nothing); 130
    stopped by SIGINT (Ctrl-C) and 143 by SIGTERM, after the command's own clean-ups ran (the
    signals raise :class:`crowdsim.jobs.Interrupted` while a command runs), with one line
    ``crowdsim <command>: interrupted by SIGINT; <what was cleaned up or kept>``.

    Every expected failure ends as one line ``crowdsim <command>: error: <message>``:
    ``ValueError`` (bad input; ``UsageError`` included), any ``OSError`` (full disk, permission,
    read-only file system, a path under a regular file, a folder where a file is expected;
    the message names the path) and ``MemoryError``. Outputs are written atomically, so none
    of these leaves a half-written file behind.
    """
    process_settings()
    parser = build_parser()
    args, extra = parser.parse_known_args(argv)
    if extra:  # argparse's top-level message would not name the command
        _command_parser(parser, args).error(f"unrecognized arguments: {' '.join(extra)}")
    # the sub-command's own name too: "detector train", "bench sim"
    sub = getattr(args, "verb", None) or getattr(args, "benchmark", None)
    command = " ".join(filter(None, (args.command, sub)))
    prefix = f"crowdsim {command}: error:"
    try:
        try:
            refuse_empty_paths(args)
            with interruptible(), _notes_as_lines(command):
                return int(args.func(args) or 0)
        except BaseException as exc:  # Interrupted too: SIGINT or SIGTERM
            # or an error an interrupt caused while it unwound (interrupt_in)
            stopped = interrupt_in(exc)
            if stopped is None:
                raise
            name = getattr(stopped, "signal_name", "SIGINT")
            detail = getattr(stopped, "detail", "")
            print(
                f"crowdsim {command}: interrupted by {name}" + (f"; {detail}" if detail else ""),
                file=sys.stderr,
            )
            return EXIT_CODES.get(name, 130)
    except ValueError as exc:
        print(f"{prefix} {exc}", file=sys.stderr)
        return 2
    except OSError as exc:
        print(f"{prefix} {describe_os_error(exc)}", file=sys.stderr)
        return 2
    except MemoryError:
        print(f"{prefix} out of memory; ask for fewer frames, agents or pixels", file=sys.stderr)
        return 2


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
