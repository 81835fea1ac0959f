"""``crowdsim.atomic``: the ledger that lets a rerun replace only the files crowdsim wrote."""

from __future__ import annotations

import json

import pytest

from crowdsim.atomic import LEDGER, record_written, require_replaceable, write_text_atomic


def test_a_file_is_replaceable_only_while_its_digest_is_the_one_written(tmp_path):
    a, b = tmp_path / "a.txt", tmp_path / "b.txt"
    assert require_replaceable("--out", a) == a  # new
    write_text_atomic(a, "one")
    write_text_atomic(b, "two")
    record_written(a, b)
    assert require_replaceable("--out", a) == a and require_replaceable("--out", b) == b
    b.write_text("two, edited")
    with pytest.raises(ValueError, match=r"--out .*b\.txt: the file exists and crowdsim"):
        require_replaceable("--out", b)
    assert require_replaceable("--out", b, overwrite=True) == b
    a.unlink()
    record_written(b)  # a.txt is gone: its entry goes too
    assert set(json.loads((tmp_path / LEDGER).read_text())["files"]) == {"b.txt"}


def test_a_foreign_file_with_the_ledgers_name_is_neither_trusted_nor_replaced(tmp_path, capsys):
    a = tmp_path / "a.txt"
    write_text_atomic(a, "one")
    from crowdsim.atomic import sha256_file

    foreign = json.dumps({"files": {"a.txt": sha256_file(a)}})  # no "written_by": not ours
    for text in (foreign, foreign[:20]):  # another program's, or damaged (truncated)
        (tmp_path / LEDGER).write_text(text)
        # the refusal and the note that cannot be taken name the ledger as the cause (an
        # --overwrite run had been silent, and every rerun asked for --overwrite again)
        with pytest.raises(ValueError, match=f"cannot prove it wrote it \\(.*{LEDGER} is dam"):
            require_replaceable("--plot", a)
        record_written(a)
        assert (tmp_path / LEDGER).read_text() == text
        err = capsys.readouterr().err
        assert f"{LEDGER} is damaged or not crowdsim's" in err and len(err.splitlines()) == 1


def test_a_ledger_that_cannot_be_written_costs_only_the_proof(tmp_path, capsys, monkeypatch):
    import errno

    import crowdsim.atomic

    a = tmp_path / "a.txt"
    write_text_atomic(a, "one")

    def full_disk(path, text):
        raise OSError(errno.ENOSPC, "No space left on device", str(path))

    monkeypatch.setattr(crowdsim.atomic, "write_text_atomic", full_disk)
    record_written(a)
    assert "could not note the written files" in capsys.readouterr().err
    assert a.read_text() == "one" and not (tmp_path / LEDGER).exists()
    with pytest.raises(ValueError, match="pass --overwrite"):  # the next run asks
        require_replaceable("--out", a)


def test_recorded_notes_what_the_block_wrote_however_it_ends(tmp_path):
    """A failure after the first of two outputs still notes the first; an untouched file
    (the user's, or not written this time) is not noted."""
    from crowdsim.atomic import recorded

    a, b, c = tmp_path / "a.txt", tmp_path / "b.txt", tmp_path / "c.txt"
    c.write_text("mine")
    with pytest.raises(OSError), recorded(a, b, c):
        write_text_atomic(a, "one")
        raise OSError(28, "No space left on device", str(b))
    assert set(json.loads((tmp_path / LEDGER).read_text())["files"]) == {"a.txt"}
    assert require_replaceable("--out", a) == a
    with pytest.raises(ValueError, match="c.txt: the file exists"):
        require_replaceable("--out", c)


def test_ctrl_c_right_after_an_output_is_renamed_in_still_lets_a_rerun_replace_it(
    tmp_path, monkeypatch
):
    import os

    from crowdsim import atomic
    from crowdsim.cli import main

    out = tmp_path / "t.npz"
    argv = ["simulate", "counterflow", "--agents", "5", "--steps", "2", "--no-progress"]
    real = os.replace

    def replace_then_ctrl_c(src, dst):
        real(src, dst)
        if os.fspath(dst) == str(out):
            raise KeyboardInterrupt  # after the rename, before the ledger

    monkeypatch.setattr(atomic.os, "replace", replace_then_ctrl_c)
    assert main([*argv, "--out", str(out)]) != 0
    monkeypatch.setattr(atomic.os, "replace", real)
    assert main([*argv, "--out", str(out)]) == 0  # crowdsim's own file: replaced, no flag


def test_bench_fd_failing_after_its_first_picture_lets_the_rerun_replace_it(tmp_path, monkeypatch):
    from crowdsim import plotting
    from crowdsim.cli import main

    real = plotting.save_figure
    calls = []

    def second_fails(fig, path, *args, **kwargs):
        calls.append(path)
        if len(calls) == 2:  # lanes.png: the disk is full
            raise OSError(28, "No space left on device", str(path))
        return real(fig, path, *args, **kwargs)

    argv = ["bench", "fd", "--densities", "1", "--length", "6.5", "--width", "3", "--warmup"]
    argv += ["0.2", "--measure", "0.24", "--lane-seconds", "0.2", "--out", str(tmp_path / "b")]
    monkeypatch.setattr(plotting, "save_figure", second_fails)
    assert main(argv) == 2
    assert (tmp_path / "b" / "fd.png").is_file()
    monkeypatch.setattr(plotting, "save_figure", real)
    assert main(argv) == 0


def test_a_study_database_this_run_half_made_is_removed_an_earlier_one_kept(tmp_path):
    from crowdsim.atomic import new_study_files

    db = tmp_path / "study.db"
    with pytest.raises(OSError), new_study_files(f"sqlite:///{db}"):
        db.write_bytes(b"SQLite format 3\0 half made")
        (tmp_path / "study.db-journal").write_bytes(b"...")
        raise OSError(28, "database or disk is full")
    assert list(tmp_path.iterdir()) == []
    db.write_bytes(b"an earlier study")  # there before the run: never removed
    with pytest.raises(ValueError), new_study_files(f"sqlite:///{db}"):
        raise ValueError("made for another objective")
    assert db.read_bytes() == b"an earlier study"
    with new_study_files("postgresql://host/db"):  # no files of its own to look after
        pass


def test_runs_noting_files_in_one_folder_at_once_keep_each_others_notes(tmp_path, monkeypatch):
    # two track --out runs finishing at once in a shared folder: the second's note is taken
    # while the first has read the ledger and not yet written it back
    import threading

    from crowdsim import atomic

    a, b = write_text_atomic(tmp_path / "a.txt", "a"), write_text_atomic(tmp_path / "b.txt", "b")
    real = atomic._ledger
    other = threading.Thread(target=record_written, args=(b,))

    def read_then_let_the_other_run_note(folder):
        listed = real(folder)
        if not other.is_alive() and other.ident is None:
            other.start()
            other.join(0.5)  # it waits for this run's note (before: it wrote meanwhile)
        return listed

    monkeypatch.setattr(atomic, "_ledger", read_then_let_the_other_run_note)
    record_written(a)
    other.join(10)
    monkeypatch.setattr(atomic, "_ledger", real)
    assert require_replaceable("--out", a) == a and require_replaceable("--out", b) == b


def test_two_runs_opening_one_new_study_take_turns_and_keep_each_others_database(tmp_path):
    # two tune runs sharing a new --study: the second waits until the first has made the
    # database, so a failure of the second never removes the database the first is using
    import threading
    import time

    from crowdsim.atomic import new_study_files

    db = tmp_path / "study.db"
    url = f"sqlite:///{db}"
    inside = threading.Event()

    def first() -> None:
        with new_study_files(url):
            inside.set()
            time.sleep(0.3)
            db.write_bytes(b"the first run's study")

    run = threading.Thread(target=first)
    run.start()
    assert inside.wait(10)
    with pytest.raises(ValueError), new_study_files(url):
        run.join(10)
        raise ValueError("the second run fails")
    assert db.read_bytes() == b"the first run's study"


def test_a_study_storage_that_fails_mid_run_ends_as_one_os_error(tmp_path, study_disk_full):
    from crowdsim.atomic import describe_os_error, study_storage

    db = tmp_path / "study.db"
    with pytest.raises(OSError) as info, study_storage(f"sqlite:///{db}"):
        study_disk_full()
    assert (
        describe_os_error(info.value) == f"{db}: the study storage failed: database or disk is full"
    )
    with pytest.raises(KeyError), study_storage(f"sqlite:///{db}"):  # not the storage's
        raise KeyError("the objective's own bug")


def test_torch_reports_a_full_disk_as_a_runtime_error_we_name_the_file(tmp_path, monkeypatch):
    torch = pytest.importorskip("torch", reason="the head detector's weights need torch")
    from crowdsim.atomic import atomic_path, describe_os_error, torch_save

    def full(obj, path):
        with open(path, "wb") as fh:
            fh.write(b"PK half")
        raise RuntimeError("[enforce fail at inline_container.cc:595] . PytorchStreamWriter "
                           "failed writing file data/0: file write failed")  # fmt: skip

    monkeypatch.setattr(torch, "save", full)
    out = tmp_path / "w.pt"
    with pytest.raises(OSError) as caught, atomic_path(out) as tmp:
        torch_save({"a": 1}, tmp, out)
    assert describe_os_error(caught.value).startswith(f"{out}: could not be written (")
    assert "is the disk full?" in str(caught.value) and list(tmp_path.iterdir()) == []


def test_a_folder_holding_only_a_killed_writes_temporary_files_counts_as_empty(tmp_path):
    """``calibrate`` and ``detector train`` want a new or empty folder; a kill at their first
    rename left a hidden temporary file there, and every rerun was refused."""
    from crowdsim.atomic import atomic_path, holds_only_leftovers
    from crowdsim.lab.detector import TrainConfig, _check_out

    with pytest.raises(KeyboardInterrupt), atomic_path(tmp_path / "calibrate.json") as tmp:
        tmp.write_text("{")
        raise KeyboardInterrupt
    leftover = tmp_path / ".calibrate.k3j_9x2a.json"  # as a SIGKILL leaves it (no cleanup)
    leftover.write_text("{")
    assert holds_only_leftovers(tmp_path) and _check_out(tmp_path, TrainConfig()) is None
    assert leftover.exists()  # never deleted: its name proves nothing
    (tmp_path / "notes.txt").write_text("mine")
    assert not holds_only_leftovers(tmp_path)
    with pytest.raises(ValueError, match="did not make"):
        _check_out(tmp_path, TrainConfig())


def test_a_checked_output_is_replaced_only_while_it_is_as_checked(tmp_path):
    """``require_replaceable`` vouches for the state of the output at the check: this run may
    write it (again and again: each write is the state the next may replace), but a file
    that appears there, or an edit, in between is kept and the write refused by name."""
    out = tmp_path / "table.md"
    require_replaceable("--out", out)
    write_text_atomic(out, "one")
    write_text_atomic(out, "two")  # the run's own file, rewritten
    out.write_text("my edit")
    with pytest.raises(FileExistsError, match="table.md: a file appeared there"):
        write_text_atomic(out, "three")
    assert out.read_text() == "my edit"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["table.md"]  # no temporary left
    new = tmp_path / "new.md"
    require_replaceable("--out", new)
    new.write_text("mine")  # appeared during the work
    with pytest.raises(FileExistsError, match="new.md: a file appeared there"):
        write_text_atomic(new, "ours")
    assert new.read_text() == "mine"
    require_replaceable("--out", new, overwrite=True)  # the user says replace it
    write_text_atomic(new, "ours")
    assert new.read_text() == "ours"


def test_a_file_kept_once_does_not_stop_a_later_run_from_noting_its_own(tmp_path):
    """One process, two runs: the first finds a user's file at its output (kept, refused);
    the user moves it away and runs again: that run's file is noted, so a third run may
    replace it without ``--overwrite``."""
    from crowdsim.atomic import recorded

    out = tmp_path / "res.txt"
    require_replaceable("--out", out)
    out.write_text("user")
    with pytest.raises(FileExistsError), recorded(out):
        write_text_atomic(out, "ours")
    out.unlink()
    require_replaceable("--out", out)
    with recorded(out):
        write_text_atomic(out, "ours")
    assert require_replaceable("--out", out) == out


def test_recorded_never_notes_a_users_file_at_an_output_the_run_did_not_write(tmp_path):
    """A Ctrl-C after the first output, while a user's file appeared at the second: the first
    is noted, the user's file is not (a rerun must not replace it without ``--overwrite``)."""
    from crowdsim.atomic import recorded

    a, b = tmp_path / "a.txt", tmp_path / "b.txt"
    require_replaceable("--out", a)
    require_replaceable("--plot", b)
    with pytest.raises(KeyboardInterrupt), recorded(a, b):
        write_text_atomic(a, "ours")
        b.write_text("mine")
        raise KeyboardInterrupt
    assert require_replaceable("--out", a) == a
    with pytest.raises(ValueError, match="cannot prove it wrote it"):
        require_replaceable("--plot", b)


def test_an_output_deleted_since_the_check_is_written(tmp_path):
    """The check vouched for a file that is gone by the write: nothing is there to keep."""
    out = tmp_path / "c.txt"
    require_replaceable("--out", out)
    write_text_atomic(out, "1")
    out.unlink()
    write_text_atomic(out, "2")
    assert out.read_text() == "2"


def test_a_sigterm_right_after_the_temporary_file_is_made_leaves_no_file(tmp_path, monkeypatch):
    """Seen by injection: SIGTERM landing between mkstemp and the clean-up's try left
    ``.<stem>.XXXXXXXX<suffix>`` behind."""
    import os
    import signal
    import tempfile

    from crowdsim.atomic import write_text_atomic
    from crowdsim.jobs import Interrupted, interruptible

    made = tempfile.mkstemp

    def mkstemp(*args, **kwargs):
        fd, name = made(*args, **kwargs)
        os.kill(os.getpid(), signal.SIGTERM)  # delivered here unless held
        return fd, name

    monkeypatch.setattr(tempfile, "mkstemp", mkstemp)
    with pytest.raises(Interrupted), interruptible():
        write_text_atomic(tmp_path / "out.txt", "x")
    assert sorted(p.name for p in tmp_path.iterdir()) == []


def test_a_sigterm_landing_as_recorded_starts_noting_still_notes_the_files(tmp_path, monkeypatch):
    """Seen by injection on ``track``: SIGTERM landing while ``signals_held`` swapped the
    handlers skipped the ledger, and the rerun refused the run's own output."""
    import os
    import signal

    from crowdsim.atomic import recorded, require_replaceable, write_text_atomic
    from crowdsim.jobs import Interrupted, interruptible

    out = tmp_path / "res.txt"
    require_replaceable("--out", out)
    getsignal = signal.getsignal
    sent = []

    def landing(s):
        if not sent:
            sent.append(s)
            os.kill(os.getpid(), signal.SIGTERM)
        return getsignal(s)

    with pytest.raises(Interrupted), interruptible():
        with recorded(out):
            write_text_atomic(out, "1,1,10,10\n")
            monkeypatch.setattr(signal, "getsignal", landing)
    monkeypatch.undo()
    assert sent and require_replaceable("--out", out) == out


def test_a_run_whose_second_output_changed_since_the_check_writes_neither(tmp_path):
    """Seen racing two ``simulate --out o.npz --plot o.png`` with other seeds over a first
    run's files: one checked them while the other rewrote them (its ``o.npz`` the same bytes,
    so still vouched for by the ledger, its ``o.png`` not yet rewritten); it then replaced
    ``o.npz`` with its own and was refused at ``o.png``: one run's trajectories beside the
    other's plot. It is refused before it writes either."""
    import os

    from crowdsim.atomic import recorded

    npz, png = tmp_path / "o.npz", tmp_path / "o.png"
    require_replaceable("--out", npz)
    require_replaceable("--plot", png)
    with recorded(npz, png):  # the first run
        write_text_atomic(npz, "seed 0")
        write_text_atomic(png, "seed 0")
    require_replaceable("--out", npz)  # the run with other settings checks ...
    require_replaceable("--plot", png)
    (tmp_path / "other").write_text("seed 0")  # ... while the other run rewrites the plot
    os.replace(tmp_path / "other", png)
    with pytest.raises(FileExistsError, match="o.png: a file appeared there"):
        with recorded(npz, png):
            write_text_atomic(npz, "seed 1")
            write_text_atomic(png, "seed 1")
    assert (npz.read_text(), png.read_text()) == ("seed 0", "seed 0")
