"""Bad input to calibrate, compare, ablation, difficulty, evaluate and the lab's Python API
(issue 13): every case ends in one named line before any work, and leaves nothing behind.

The table commands refuse before generating anything, so no case tracks a sequence: a case
either fails on its flags, on a file it was given (a study, a suite folder, ``cells.json``,
``paper.json``, the output folder's ``calibrate.json``) or on a call of the lab's API.
"""

from __future__ import annotations

import json
import shutil
import sqlite3
from pathlib import Path

import numpy as np

from battery.harness import SPEC, Env, api_case, case, seq_copy

PAPER_SPEC = SPEC + "\n[calibration]\npaper_b_ncc_15px = 50.0\npaper_ncc_15px = 50.0\n"
RECORD = {
    "format": 1,
    "written_by": "crowdsim calibrate",
    "source": "ucf9",
    "files": {},
    "results": {},
}


def _record(**fields) -> str:
    return json.dumps({**RECORD, **fields})


def _sqlite(path: Path, *statements: str) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    con = sqlite3.connect(path)
    for sql in statements:
        con.execute(sql)
    con.commit()
    con.close()


def _db(*statements: str, name: str = "s.db"):
    def setup(w: Path, env: Env) -> None:
        _sqlite(w / name, *statements)

    return setup


FOREIGN_OPTUNA = (
    "CREATE TABLE studies (study_id INTEGER PRIMARY KEY, study_name TEXT)",
    "CREATE TABLE trials (trial_id INTEGER PRIMARY KEY)",
    "CREATE TABLE version_info (version_info_id INTEGER PRIMARY KEY)",
    "CREATE TABLE study_user_attributes (study_user_attribute_id INTEGER PRIMARY KEY, "
    "study_id INTEGER, key TEXT, value_json TEXT)",
    "INSERT INTO studies VALUES (1, 'crowdsim-tune')",
)


def _mot_folder(w: Path, env: Env) -> None:
    shutil.copytree(env.seq, w / "m" / "seq")


def _existing_sequence(w: Path, env: Env) -> None:
    """``{w}/o/sequences/tiny``: a sequence folder made from another spec than ``{w}/s``'s."""
    shutil.copytree(env.seq, w / "o" / "sequences" / "tiny")


def _cells(edit) -> str:
    """A ``cells.json`` with one cell sealed as ``compare`` seals it, then ``edit``ed."""
    from crowdsim.lab.experiments import seal_cell

    key = "seq1|ncc|params=000000000000|frames=all"
    data = {"format": 1, "cells": {key: seal_cell(key, {"acc@15": 85.4, "curve": []})}}
    edit(data["cells"][key])
    return json.dumps(data)


EDITED_CELLS = _cells(lambda c: c.update({"acc@15": 999.0}))
UNSEALED_CELLS = _cells(lambda c: c.pop("sha256"))

# --- calibrate: flags ---------------------------------------------------------------------
CAL = "calibrate --out {w}/o"
case("tables-cal-no-out", "calibrate --suite ucf9", "the following arguments are required: --out")
case("tables-cal-trials-0", f"{CAL} --trials 0", "--trials must be an integer in [1, 200], got 0")
case("tables-cal-trials-huge", f"{CAL} --trials 100000", "got 100000")
case("tables-cal-trials-neg", f"{CAL} --trials -3", "--trials must be&&got -3")
case("tables-cal-trials-text", f"{CAL} --trials many", "invalid int value: 'many'")
case("tables-cal-force-alone", f"{CAL} --force", "--force needs --update-suite")
case("tables-cal-only-unknown", f"{CAL} --only seq99", "no sequence 'seq99' in suite 'ucf9'")
case("tables-cal-galleria", f"{CAL} --suite galleria", "no spec records [calibration] paper_b_ncc")
case(
    "tables-cal-anchor-unknown",
    f"{CAL} --anchor kcf",
    "--anchor must be one of ('b-ncc', 'ncc11'), got 'kcf'",
)
case(
    "tables-cal-anchor-no-figures",
    f"{CAL} --suite {{w}}/s",
    "no spec records [calibration] paper_b_ncc_15px, the target of --anchor b-ncc (it has "
    "figures for --anchor ncc11)",
    files=(("s/tiny.toml", SPEC + "\n[calibration]\npaper_ncc_15px = 50\n"),),
)

# --- calibrate: suite folders ---------------------------------------------------------------
case("tables-cal-suite-missing", f"{CAL} --suite {{w}}/nosuch", "nosuch' (no such folder)")
case("tables-cal-suite-file", f"{CAL} --suite {{afile}}", "afile: is a file, not a suite folder")
case(
    "tables-cal-suite-empty",
    f"{CAL} --suite {{w}}/e",
    "no spec files (*.toml, *.yaml, *.yml) in",
    setup=lambda w, env: (w / "e").mkdir(),
)
case(
    "tables-cal-suite-of-sequences",
    f"{CAL} --suite {{w}}/m",
    "a folder of MOT sequences is for tune and heldout",
    setup=_mot_folder,
)
case(
    "tables-cal-suite-no-paper-figure",
    f"{CAL} --suite {{w}}/s",
    "no spec records [calibration] paper_b_ncc_15px",
    files=(("s/tiny.toml", SPEC),),
)
case(
    "tables-cal-suite-bad-target",
    f"{CAL} --suite {{w}}/s --anchor ncc11",
    "tiny.toml: calibration.paper_ncc_15px must be a finite number in [0, 100], got 150",
    files=(("s/tiny.toml", SPEC + "\n[calibration]\npaper_ncc_15px = 150\n"),),
)
case(
    "tables-cal-suite-text-target",
    f"{CAL} --suite {{w}}/s --anchor ncc11",
    "paper_ncc_15px must be a finite number in [0, 100], got 'high'",
    files=(("s/tiny.toml", SPEC + '\n[calibration]\npaper_ncc_15px = "high"\n'),),
)
case(
    "tables-cal-suite-duplicate-name",
    f"{CAL} --suite {{w}}/s",
    "a.toml and b.toml both name the sequence 'tiny'",
    files=(("s/a.toml", PAPER_SPEC), ("s/b.toml", PAPER_SPEC)),
)
case(
    "tables-cal-suite-broken-spec",
    f"{CAL} --suite {{w}}/s",
    "x.toml: invalid TOML",
    files=(("s/x.toml", "name = [\n"),),
)

# --- calibrate: the output folder -----------------------------------------------------------
case(
    "tables-cal-out-is-suite",
    "calibrate --suite {w}/s --out {w}/s",
    "is the suite folder itself",
    files=(("s/tiny.toml", PAPER_SPEC),),
)
case(
    "tables-cal-out-foreign",
    CAL,
    "o: not empty and not written by crowdsim calibrate (no calibrate.json)",
    files=(("o/notes.txt", "my notes\n"),),
)
case("tables-cal-out-is-file", "calibrate --out {afile}", "afile: is a file, not a folder")
case("tables-cal-out-under-file", "calibrate --out {afile}/o", "afile is a file, not a folder")
case(
    "tables-cal-record-broken",
    CAL,
    "calibrate.json: damaged",
    files=(("o/calibrate.json", "{broken"),),
)
case(
    "tables-cal-record-foreign",
    CAL,
    "calibrate.json: not a crowdsim calibrate record",
    files=(("o/calibrate.json", '{"files": []}'),),
)
case(
    "tables-cal-record-other-suite",
    CAL,
    "holds a calibration of the suite 'galleria', not 'ucf9'",
    files=(("o/calibrate.json", _record(source="galleria")),),
)
case(
    "tables-cal-out-edited-spec",
    f"{CAL} --only seq5",
    "seq5.toml: not written by crowdsim calibrate, or changed since",
    files=(
        ("o/calibrate.json", _record(files={"seq5.toml": ["0" * 64]})),
        ("o/seq5.toml", "# my own edit\n"),
    ),
)
case(
    "tables-cal-out-users-readme",
    f"{CAL} --only seq5",
    "README.md: not written by crowdsim calibrate, or changed since",
    files=(("o/calibrate.json", _record()), ("o/README.md", "# mine\n")),
)

# --- calibrate: study files -----------------------------------------------------------------
case(
    "tables-cal-study-text",
    f"{CAL} --study {{afile}}",
    "afile: not an SQLite file",
)
case(
    "tables-cal-study-foreign-sqlite",
    f"{CAL} --study {{w}}/s.db",
    "s.db: an SQLite database that is not an Optuna study (tables people)",
    setup=_db("CREATE TABLE people (id INTEGER)"),
)
case(
    "tables-cal-study-foreign-optuna",
    f"{CAL} --study {{w}}/s.db",
    "holds the Optuna study 'crowdsim-tune', not made by crowdsim calibrate",
    setup=_db(*FOREIGN_OPTUNA),
)
case(
    "tables-cal-study-damaged-sqlite",
    f"{CAL} --study {{w}}/s.db",
    "s.db: a damaged SQLite file",
    files=(("s.db", b"SQLite format 3\x00" + b"\xff" * 200),),
)
case("tables-cal-study-folder", f"{CAL} --study {{w}}", "is a folder, not a study file")
case(
    "tables-cal-study-url",
    f"{CAL} --study postgresql://db/x",
    "--study must be an SQLite file (a path), got 'postgresql://db/x'",
)
case("tables-cal-study-no-folder", f"{CAL} --study {{w}}/none/s.db", "no such folder")
case(
    "tables-cal-default-study-foreign",
    CAL,
    "calibration.db: not an SQLite file",
    files=(("o/calibrate.json", _record()), ("o/calibration.db", "a text file\n")),
)

case(
    "tables-cal-out-readonly",
    "calibrate --out {ro}",
    "--out {ro}: the folder is not writable",
    needs="ro",
)
case(
    "tables-cal-out-under-readonly",
    "calibrate --out {ro}/o",
    "--out {ro}/o: the folder {ro} is not writable",
    needs="ro",
)
case(
    # it had copied the suite into --out, then failed on SQLite's file (naming no flag)
    "tables-cal-study-readonly",
    f"{CAL} --study {{ro}}/s.db",
    "--study {ro}/s.db: the folder {ro} is not writable",
    needs="ro",
)
case(
    "tables-cal-suite-broken-yaml",
    f"{CAL} --suite {{w}}/s",
    "x.yaml: invalid YAML",
    files=(("s/tiny.toml", PAPER_SPEC), ("s/x.yaml", "name: [\n")),
)

# --- compare, ablation, difficulty ----------------------------------------------------------
CMP = "compare --out {w}/o"
for command in ("compare", "ablation", "difficulty"):
    short = command[:4]
    case(
        f"tables-{short}-address-without-ray",
        f"{command} --address 10.0.0.1:6379 --out {{w}}/o",
        "--address needs --backend ray, got --address '10.0.0.1:6379'",
    )
    case(
        f"tables-{short}-cells-edited",
        f"{command} --out {{w}}/o",
        "cells.json: cell 'seq1|ncc|&&does not match its checksum",
        files=(("o/cells.json", EDITED_CELLS),),
    )
    case(
        f"tables-{short}-suite-missing",
        f"{command} --suite {{w}}/nosuch --out {{w}}/o",
        "nosuch' (no such folder)",
    )
case(
    "tables-comp-cells-unsealed",
    CMP,
    "does not match its checksum",
    files=(("o/cells.json", UNSEALED_CELLS),),
)
case(
    "tables-comp-cells-binary",
    CMP,
    "cells.json: not a crowdsim cells file (damaged",
    files=(("o/cells.json", b"\x89PNG\r\n\x1a\n\x00\x00"),),
)
case(
    "tables-comp-cells-foreign",
    CMP,
    "cells.json: not a crowdsim cells file (no 'cells' object)",
    files=(("o/cells.json", '{"cells": [1, 2]}'),),
)
case(
    "tables-comp-cells-folder",
    CMP,
    "cells.json: is a folder, not a cells file",
    setup=lambda w, env: (w / "o" / "cells.json").mkdir(parents=True),
)
case(
    "tables-comp-foreign-sequences-manifest",
    CMP,
    "sequences/manifest.json: not a crowdsim manifest&&refusing to replace it",
    files=(("o/sequences/manifest.json", '{"project": "mine"}'),),
)
case("tables-comp-frames-1", f"{CMP} --frames 1", "--frames must be an integer >= 2, got 1")
case(
    "tables-comp-workers-0", f"{CMP} --workers 0", "--workers must be an integer in [1, 256], got 0"
)
case(
    "tables-comp-workers-above-cores",
    f"{CMP} --workers 256",
    "--workers must be in [1, &&(os.cpu_count()), got 256",
)
case("tables-comp-only-unknown", f"{CMP} --only seq10", "no sequence 'seq10' in suite 'ucf9'")
case(
    "tables-comp-suite-empty",
    "compare --suite {w}/e --out {w}/o",
    "no spec files (*.toml, *.yaml, *.yml)",
    setup=lambda w, env: (w / "e").mkdir(),
)
case(
    "tables-comp-paper-json-broken",
    "compare --suite {w}/s --out {w}/o",
    "paper.json: not a papers' figures file (broken JSON",
    files=(("s/tiny.toml", SPEC), ("s/paper.json", "{")),
)
case(
    "tables-comp-paper-json-value",
    "compare --suite {w}/s --out {w}/o",
    "paper.json: acc@15.NCC.tiny must be a percentage in [0, 100], got 'high'",
    files=(("s/tiny.toml", SPEC), ("s/paper.json", '{"acc@15": {"NCC": {"tiny": "high"}}}')),
)
case(
    "tables-comp-paper-json-list",
    "ablation --suite {w}/s --out {w}/o",
    "paper.json: must be a JSON object of tables, got list",
    files=(("s/tiny.toml", SPEC), ("s/paper.json", "[1]")),
)
case(
    "tables-comp-sequence-from-another-spec",
    "compare --suite {w}/s --out {w}/o",
    "exists and&&remove that folder, or choose another --out",
    files=(("s/tiny.toml", SPEC),),
    setup=_existing_sequence,
)

# --- compare / ablation --sequences: the user's own MOT sequences ---------------------------
SEQS = "--trackers ncc --no-progress --out {w}/o"


def _seq_edit(edit):
    """``{w}/m/seq``: a copy of the shared sequence without ``checksums.json`` (as real MOT
    footage comes), ``edit``ed."""

    def setup(w: Path, env: Env) -> None:
        _mot_folder(w, env)
        (w / "m" / "seq" / "checksums.json").unlink()
        edit(w / "m" / "seq")

    return setup


def _bad_video(s: Path) -> None:
    shutil.rmtree(s / "img1")
    (s / "video.mp4").write_bytes(b"\x00" * 4096)


for command in ("compare", "ablation"):
    short = command[:4]
    case(
        f"tables-{short}-sequences-empty",
        f"{command} --sequences {{w}}/e --no-progress --out {{w}}/o",
        "{w}/e: no MOT sequence folders (sub-folders with seqinfo.ini)",
        setup=lambda w, env: (w / "e").mkdir(),
    )
    case(
        f"tables-{short}-sequences-missing",
        f"{command} --sequences {{w}}/nosuch --no-progress --out {{w}}/o",
        "--sequences {w}/nosuch: no such folder",
    )
case(
    "tables-comp-sequences-file",
    f"compare --sequences {{afile}} {SEQS}",
    "--sequences {afile}: is a file, not a folder of MOT sequences",
)
case(
    "tables-comp-sequences-no-gt",
    f"compare --sequences {{w}}/m {SEQS}",
    "{w}/m/seq: no ground truth (gt/gt.txt) to score",
    setup=_seq_edit(lambda s: (s / "gt" / "gt.txt").unlink()),
)
case(
    "tables-comp-sequences-video-unreadable",
    f"compare --sequences {{w}}/m {SEQS}",
    "{w}/m/seq/video.mp4: could not read frame 1",
    setup=_seq_edit(_bad_video),
)
case(
    "tables-comp-sequences-out-inside",
    "compare --sequences {w}/m --trackers ncc --no-progress --out {w}/m/o",
    "--out {w}/m/o: inside --sequences {w}/m",
    setup=_mot_folder,
)
case(
    "tables-comp-sequences-only-unknown",
    f"compare --sequences {{w}}/m --only nosuch {SEQS}",
    "--only: no sequence 'nosuch' in {w}/m; choose from seq",
    setup=_mot_folder,
)
case(
    "tables-comp-sequences-and-suite",
    f"compare --suite ucf9 --sequences {{seq}} {SEQS}",
    "argument --sequences: not allowed with argument --suite",
)
case(
    "tables-diff-sequences",
    "difficulty --sequences {seq} --out {w}/o",
    "unrecognized arguments: --sequences",
)
case(
    "tables-gen-suite-missing",
    "generate --suite {w}/nosuch --out {w}/o",
    "--suite must be one of ucf9, ucf9-shake, ucf9-drone, galleria, stress or a suite folder "
    "of spec files",
)
case(
    "tables-gen-suite-of-sequences",
    "generate --suite {w}/m --out {w}/o",
    "no spec files (*.toml, *.yaml, *.yml)&&a folder of MOT sequences is for tune and heldout",
    setup=_mot_folder,
)
case(
    "tables-diff-trackers-unknown",
    "difficulty --trackers nosuch --out {w}/o",
    "nosuch",
)
case(
    "tables-diff-trackers-twice",
    "difficulty --trackers ncc ncc --out {w}/o",
    "--trackers: ncc, ncc names a tracker twice",
)
case(
    "tables-compare-trackers-unknown",
    "compare --trackers bqp nosuch --out {w}/o",
    "unknown tracker 'nosuch'; valid trackers: bqp",
)
case(
    "tables-compare-set-twice",
    "compare --trackers bqp --set zeta=0.3 --set zeta=0.4 --out {w}/o",
    "--set zeta is given twice",
)
case(
    "tables-compare-set-unknown",
    "compare --set nosuch=1 --out {w}/o",
    "--set nosuch: no row's tracker has that parameter&&bqp",
)
case(
    "tables-compare-set-no-value",
    "compare --set fw_variant --out {w}/o",
    "--set expects NAME=VALUE, got 'fw_variant'",
)
case(
    "tables-ablation-set-own-term",
    "ablation --set zeta=0.5 --out {w}/o",
    "--set zeta: row 'B (NCC)' sets zeta itself",
)
case(
    "tables-diff-groups-unknown",
    "difficulty --groups shake wobble --out {w}/o",
    "--groups: unknown group 'wobble'&&shake",
)
case(
    "tables-diff-groups-twice",
    "difficulty --groups shake shake --out {w}/o",
    "--groups: name each group once",
)
case(
    "tables-diff-cmc-detection-tracker",
    "difficulty --trackers bytetrack --cmc --out {w}/o",
    "--cmc: tracker 'bytetrack' has no camera-motion compensation",
)
case(
    "tables-diff-not-calibrated",
    "difficulty --suite {w}/s --out {w}/o",
    "no calibrated sequence to attribute",
    files=(("s/tiny.toml", SPEC),),
)

DIF = "difficulty --out {w}/o"
case(
    "tables-diff-frames-negative", f"{DIF} --frames -5", "--frames must be an integer >= 2, got -5"
)
case("tables-diff-frames-0", f"{DIF} --frames 0", "--frames must be an integer >= 2, got 0")
case(
    "tables-diff-only-unknown", f"{DIF} --only seq99", "--only: no sequence 'seq99' in suite 'ucf9'"
)
case(
    "tables-diff-out-is-file", "difficulty --out {afile}", "--out {afile}: is a file, not a folder"
)
case(
    "tables-diff-out-readonly",
    "difficulty --out {ro}",
    "--out {ro}: the folder is not writable",
    needs="ro",
)
case(
    "tables-diff-out-under-readonly",
    "difficulty --out {ro}/o",
    "--out {ro}/o: the folder {ro} is not writable",
    needs="ro",
)
case(
    "tables-diff-suite-broken-toml",
    "difficulty --suite {w}/s --out {w}/o",
    "x.toml: invalid TOML",
    files=(("s/tiny.toml", PAPER_SPEC), ("s/x.toml", "name = [\n")),
)
case(
    "tables-diff-suite-broken-yaml",
    "difficulty --suite {w}/s --out {w}/o",
    "x.yaml: invalid YAML",
    files=(("s/tiny.toml", PAPER_SPEC), ("s/x.yaml", "name: [\n")),
)
case(
    "tables-diff-only-not-calibrated",
    "difficulty --suite {w}/s --only tiny --out {w}/o",
    "tiny: not calibrated (no base_* values in [calibration])",
    files=(("s/tiny.toml", PAPER_SPEC),),
)

# --- evaluate -------------------------------------------------------------------------------
case(
    "tables-eval-results-binary",
    "evaluate {w}/r.txt {seq}",
    "r.txt: not a MOT text file (binary, not UTF-8 text",
    files=(("r.txt", b"\xfa\xfb\x00\x01binary"),),
)
_BINARY_GT = seq_copy(lambda s: (s / "gt" / "gt.txt").write_bytes(b"\xfa\xfb\x00binary"), False)
_BINARY_INI = seq_copy(lambda s: (s / "seqinfo.ini").write_bytes(b"\xff\xfe\x00garbage"), True)
for _cmd, _argv in (("eval", "evaluate {res} {w}/s"), ("track", "track {w}/s --out {w}/r.txt")):
    case(
        f"tables-{_cmd}-gt-binary",
        _argv,
        "gt.txt: not a MOT text file (binary, not UTF-8 text",
        setup=_BINARY_GT,
    )
    case(
        f"tables-{_cmd}-seqinfo-binary",
        _argv,
        "seqinfo.ini: not a seqinfo.ini file (binary, not UTF-8 text",
        setup=_BINARY_INI,
    )
case(
    "tables-eval-semicolons",
    "evaluate {w}/r.txt {seq}",
    "r.txt:1: expected at least 6 columns",
    files=(("r.txt", "1;1;4;6;12;12\n"),),
)
case(
    "tables-eval-plot-over-results",
    "evaluate {w}/r.png {seq} --plot {w}/r.png --overwrite",
    "would overwrite or sit inside the input RESULTS",
    files=(("r.png", "1,1,4,6,12,12\n"),),
)


# --- the lab's Python API -------------------------------------------------------------------
def _tiny_spec():
    from synth_data.spec import parse_spec_text, spec_from_dict

    return spec_from_dict(parse_spec_text(SPEC, "toml", "tiny.toml"), source="tiny.toml")


def _run_table(w: Path, rows=None, **kw):
    from crowdsim.lab.experiments import Row, run_table

    rows = rows if rows is not None else (Row("NCC", "ncc"),)
    return run_table(rows, [_tiny_spec()], w / "o", progress=False, log=lambda m: None, **kw)


def _rows(*pairs):
    from crowdsim.lab.experiments import Row

    return tuple(Row(label, tracker, over) for label, tracker, over in pairs)


api_case(
    "tables-api-run-table-address",
    lambda w, env: _run_table(w, address="ray://x:10001"),
    "--address needs --backend ray, got --address 'ray://x:10001'",
)
api_case(
    "tables-api-run-table-same-label",
    lambda w, env: _run_table(w, _rows(("A", "ncc", {}), ("A", "bqp", {}))),
    "two rows share the label 'A'",
)
api_case(
    "tables-api-run-table-same-cell",
    lambda w, env: _run_table(w, _rows(("A", "bqp", {"zeta": 2.0}), ("B", "bqp", {"zeta": 2.0}))),
    "rows 'A' and 'B' run the same tracker with the same parameters",
)
api_case(
    "tables-api-run-table-only-unknown",
    lambda w, env: _run_table(w, only=["nope"]),
    "--only: no sequence 'nope' among the specs",
)
api_case(
    "tables-api-run-table-frames-float",
    lambda w, env: _run_table(w, frames=2.5),
    "--frames must be an integer >= 2, got 2.5",
)
api_case(
    "tables-api-read-cells-edited",
    lambda w, env: __import__("crowdsim.lab.experiments").lab.experiments.read_cells(
        w / "cells.json"
    ),
    "cells.json: cell 'seq1|ncc|",
    files=(("cells.json", EDITED_CELLS),),
)


def _calibrate_spec(**kw):
    from crowdsim.lab.calibration import calibrate_spec

    return calibrate_spec(_tiny_spec(), kw.pop("target", 50.0), log=lambda m: None, **kw)


api_case(
    "tables-api-calibrate-target",
    lambda w, env: _calibrate_spec(target=150.0),
    "calibrate_spec.target must be a finite number in [0, 100], got 150.0",
)
api_case(
    "tables-api-calibrate-trials-float",
    lambda w, env: _calibrate_spec(trials=2.5),
    "calibrate_spec.trials must be an integer in [1, 200], got 2.5",
)
api_case(
    "tables-api-calibrate-trials-bool",
    lambda w, env: _calibrate_spec(trials=True),
    "got True",
)
api_case(
    "tables-api-calibrate-foreign-storage",
    lambda w, env: _calibrate_spec(storage=f"sqlite:///{env.afile}"),
    "afile: not an SQLite file",
)


def _calibrate_suite(w: Path, **kw):
    from crowdsim.lab.calibration import calibrate_suite

    return calibrate_suite(kw.pop("suite", "ucf9"), out=w / "o", log=lambda m: None, **kw)


api_case(
    "tables-api-calibrate-suite-trials-text",
    lambda w, env: _calibrate_suite(w, trials="3"),
    "--trials must be an integer in [1, 200], got '3'",
)
api_case(
    "tables-api-calibrate-suite-only-string",
    lambda w, env: _calibrate_suite(w, only="seq99"),
    "no sequence 'seq99'",
)
api_case(
    "tables-api-calibrate-suite-not-a-name",
    lambda w, env: _calibrate_suite(w, suite=9),
    "--suite must be one of ucf9, ucf9-shake, ucf9-drone, galleria, stress or a suite folder "
    "of spec files, got 9",
)
api_case(
    "tables-api-write-calibration-not-a-spec",
    lambda w, env: __import__("crowdsim.lab.calibration").lab.calibration.write_calibration(
        w / "x.toml", {"values": {}, "difficulty": 0.0, "score_15px": 1.0, "trials": 1}
    ),
    "x.toml: invalid TOML",
    files=(("x.toml", "name = [\n"),),
)


def _attribute(w: Path, **kw):
    from crowdsim.lab.difficulty import attribute

    return attribute("ucf9", w / "o", progress=False, log=lambda m: None, **kw)


api_case(
    "tables-api-attribute-tracker-string",
    lambda w, env: _attribute(w, trackers="nosuch"),
    "nosuch",
)
api_case(
    "tables-api-attribute-no-trackers",
    lambda w, env: _attribute(w, trackers=[]),
    "--trackers: name at least one tracker",
)


def _evaluate(**kw):
    from tracker.metrics import evaluate

    gt = np.zeros((3, 2, 2))
    return evaluate([1, 2], gt, kw.pop("ids", [1, 2]), kw.pop("tr", gt), **kw)


api_case(
    "tables-api-evaluate-id-mapping",
    lambda w, env: _evaluate(id_mapping="nearest"),
    "id_mapping must be one of ('auto', 'same', 'majority'), got 'nearest'",
)
api_case(
    "tables-api-evaluate-shape",
    lambda w, env: _evaluate(tr=np.zeros((3, 3, 2))),
    "tracks must have shape (T, 2, 2), got (3, 3, 2)",
)
api_case(
    "tables-api-evaluate-unknown-strict",
    lambda w, env: _evaluate(ids=[1, 9], id_mapping="same"),
    "ids unknown to the ground truth (e.g. [9])",
)
api_case(
    "tables-api-evaluate-similarity-0",
    lambda w, env: _evaluate(similarity_scale=0.0),
    "similarity_scale must be > 0 px, got 0.0",
)
api_case(
    "tables-api-resolve-without-points",
    lambda w, env: __import__("tracker.metrics").metrics.resolve_id_mapping([1, 2], [1, 3], "auto"),
    'id_mapping="auto" with some unknown track ids needs the points',
)
api_case(
    "tables-api-paper-numbers-column",
    lambda w, env: __import__("synth_data.suites").suites.paper_numbers(w / "s"),
    "paper.json: table 'acc@15' must be an object of columns",
    files=(("s/tiny.toml", SPEC), ("s/paper.json", '{"acc@15": [1]}')),
)
