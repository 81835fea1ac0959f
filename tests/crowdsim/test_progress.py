"""The one progress bar: state lines in logs, silence for short jobs and when turned off."""

from __future__ import annotations

import time

import crowdsim.progress as progress


def test_a_bar_in_a_log_writes_its_state_lines_once_it_has_run_long_enough(monkeypatch, capsys):
    """stderr is not a terminal here (captured): no redraws, but after LOG_EVERY_S a line of
    count, rate and ETA every LOG_EVERY_S, each a whole line (a log, CI, nohup)."""
    monkeypatch.setattr(progress, "LOG_EVERY_S", 0.15)
    with progress.progress_bar(total=12, desc="tracking", unit="frame") as bar:
        for _ in range(12):
            time.sleep(0.04)
            bar.update(1)
    lines = capsys.readouterr().err.splitlines()
    assert 1 <= len(lines) <= 6, lines
    assert all(line.startswith("tracking: ") and "frame/s" in line for line in lines)
    assert "\r" not in "".join(lines)


def test_a_short_bar_or_a_disabled_one_writes_nothing(monkeypatch, capsys):
    monkeypatch.setattr(progress, "LOG_EVERY_S", 30.0)
    assert list(progress.progress_bar(range(50), desc="short")) == list(range(50))
    monkeypatch.setattr(progress, "LOG_EVERY_S", 0.0)
    with progress.progress_bar(total=3, desc="off", enabled=False) as bar:
        bar.update(3)
    assert capsys.readouterr().err == ""
