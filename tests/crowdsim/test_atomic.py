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


def test_a_foreign_file_with_the_ledgers_name_is_neither_trusted_nor_replaced(tmp_path):
    a = tmp_path / "a.txt"
    write_text_atomic(a, "one")
    from crowdsim.atomic import sha256_file

    foreign = json.dumps({"files": {"a.txt": sha256_file(a)}})  # no "written_by": not ours
    (tmp_path / LEDGER).write_text(foreign)
    with pytest.raises(ValueError, match="cannot prove it wrote it"):
        require_replaceable("--plot", a)
    record_written(a)
    assert (tmp_path / LEDGER).read_text() == foreign


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
