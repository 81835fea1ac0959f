"""The one progress bar: state lines in logs, silence for short jobs and when turned off."""

from __future__ import annotations

import time

import crowdsim.progress as progress


def test_a_bar_in_a_log_writes_its_state_lines_once_it_has_run_long_enough(monkeypatch, capsys):
    """stderr is not a terminal here (captured): no redraws, but after LOG_EVERY_S a line of
    count, rate and ETA every LOG_EVERY_S, each a whole line (a log, CI, nohup)."""
    monkeypatch.setattr(progress, "LOG_EVERY_S", 0.15)
    t0 = time.monotonic()
    with progress.progress_bar(total=12, desc="tracking", unit="frame") as bar:
        for _ in range(12):
            time.sleep(0.04)
            bar.update(1)
    elapsed = time.monotonic() - t0  # 0.48 s, or more on a loaded machine
    lines = capsys.readouterr().err.splitlines()
    assert 1 <= len(lines) <= elapsed / 0.15, lines
    assert all(line.startswith("tracking: ") and "frame/s" in line for line in lines)
    assert "\r" not in "".join(lines)


def test_a_short_bar_or_a_disabled_one_writes_nothing(monkeypatch, capsys):
    monkeypatch.setattr(progress, "LOG_EVERY_S", 30.0)
    assert list(progress.progress_bar(range(50), desc="short")) == list(range(50))
    monkeypatch.setattr(progress, "LOG_EVERY_S", 0.0)
    with progress.progress_bar(total=3, desc="off", enabled=False) as bar:
        bar.update(3)
    assert capsys.readouterr().err == ""


class _Terminal:
    """A stderr that says it is a terminal and keeps what is written."""

    def __init__(self) -> None:
        self.text = ""

    def isatty(self) -> bool:
        return True

    def write(self, text: str) -> int:
        self.text += text
        return len(text)

    def flush(self) -> None:
        pass


def test_a_bar_that_does_not_advance_keeps_its_clock_running(monkeypatch, capsys):
    """A first run compiles its kernels before the first step ends: the bar redraws anyway,
    on a terminal (its elapsed time) and in a log (a state line), and stops when closed."""
    term = _Terminal()
    monkeypatch.setattr(progress.sys, "stderr", term)
    monkeypatch.setattr(progress, "TICK_S", 0.1)

    def draws() -> list[str]:
        return [d for d in term.text.split("\r") if d.startswith("track:")]

    def clocks() -> set[str]:
        return {d.split("[")[1][:5] for d in draws()}

    with progress.progress_bar(total=5, desc="track", unit="frame"):
        # nothing advances: wait for the redraws (a loaded machine may delay the ticks)
        deadline = time.monotonic() + 30
        while (len(draws()) < 3 or len(clocks()) < 2) and time.monotonic() < deadline:
            time.sleep(0.05)
    assert len(draws()) >= 3, draws()  # the first draw, then a redraw every 0.1 s
    assert len(clocks()) >= 2  # the clock moved
    closed = len(term.text)
    time.sleep(0.3)
    assert len(term.text) == closed  # no redraw after the close
    monkeypatch.undo()
    monkeypatch.setattr(progress, "LOG_EVERY_S", 0.15)
    with progress.progress_bar(total=5, desc="compile", unit="frame"):
        time.sleep(1.4)
    lines = capsys.readouterr().err.splitlines()
    assert lines and all(line.startswith("compile:   0%") for line in lines), lines


def test_a_bar_that_redraws_for_its_postfix_still_writes_one_line_per_period(monkeypatch, capsys):
    """set_postfix redraws at once (tqdm's mininterval does not apply): in a log that had
    written a line per frame once the first period was over."""
    monkeypatch.setattr(progress, "LOG_EVERY_S", 0.2)
    t0 = time.monotonic()
    with progress.progress_bar(total=40, desc="track", unit="frame") as bar:
        for k in range(40):
            time.sleep(0.02)
            bar.set_postfix(targets=k)
            bar.update(1)
    # 0.8 s, or more on a loaded machine (1.2 s there, and 6 lines): at most one line
    # per 0.2 s of the bar's life, measured; a line per frame would be some 35
    elapsed = time.monotonic() - t0
    lines = capsys.readouterr().err.splitlines()
    assert 1 <= len(lines) <= elapsed / 0.2, lines
