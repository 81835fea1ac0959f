"""Calibrate a suite's difficulty against the papers: ``crowdsim calibrate``.

The generated crowds must be as hard as the papers' real ones. For every sequence of a suite
whose spec records the paper's figure for the chosen *anchor* (``[calibration]
paper_<key>_15px``), an Optuna study searches the sequence's *appearance and camera* knobs --
never its motion -- until the anchor's tracker scores that figure at 15 px.

The anchor (:data:`ANCHORS`, ``--anchor``)
    ``b-ncc`` (default): paper 1's own template baseline, the B(NCC) row of its Table 3 --
    "just a template-based tracker without the other terms in Eq. 1" -- matched by the same
    configuration of our BQP tracker (appearance term only, NCC appearance), on the
    ``static`` profile of the difficulty scale: a fixed camera as in the papers' footage, and
    image formation (noise, blur, flicker, JPEG, H.264) only up to what real surveillance or
    web video has (:data:`crowdsim.knobs.PROFILES`, each knob's ``static`` end and source).
    ``ncc11``: the papers' NCC column, which comes from [11]'s implementation -- paper 1 says
    its own template baseline is "30% higher" -- matched by our independent NCC tracker with
    every knob free to reach its hard end (camera shake included). Anchoring a good template
    tracker on a weak implementation's scores made every scene about 30 points too hard; the
    sequences it made are kept as the ``ucf9-shake`` suite. The spec records the anchor
    (``[calibration] anchor``) and its achieved score (``achieved_<key>_15px``).

Where the result goes
    :func:`calibrate_suite` writes a new *suite folder* ``OUT`` (``--out``): every spec file of
    the suite (the calibrated ones with their knobs and the achieved score; comments and the
    rest of each file kept), the suite's ``README.md`` (the paper's figures beside the
    achieved), a copy of its ``paper.json`` and ``calibrate.json`` (what this command wrote,
    with checksums, and the results). ``--suite OUT`` then works wherever a suite is named
    (``generate``, ``compare``, ``ablation``, ``difficulty``, ``calibrate``), so ``crowdsim
    generate --suite OUT`` reproduces the calibrated sequences exactly. The suite calibrated
    from is never touched, except with ``update_suite`` (``--update-suite``), and even then a
    sequence whose new calibration is further from the paper's figure than the one its spec
    records is kept unless ``force`` (``--force``); the log says per sequence what was kept.

Files are sacred
    ``OUT`` must be new, empty or a folder this command wrote: a file in it is only replaced
    when its checksum in ``calibrate.json`` proves it is ours and unchanged. The studies live
    in ``OUT/calibration.db`` (or ``--study FILE``), SQLite, so a killed run resumes; a study
    file that is not SQLite, an SQLite database with other tables, or an Optuna file holding a
    study this command did not make is refused before anything is written
    (:func:`check_study_file`), so no Optuna table is ever added to someone else's database.
    Every check runs before the first write: a refused run leaves nothing behind.

Search space: one difficulty ``d`` in [0, 1] moving the knobs of both calibration axes of
:data:`crowdsim.knobs.KNOBS` from the spec's own values (0) to their ends under the anchor's
profile (1) (:func:`crowdsim.knobs.knob_values`):

* ``scene`` -- look-alike heads and clothing, packed bodies, gait, arm swing and head turns,
  clutter and moving shadows;
* ``camera`` -- sensor noise, defocus, flicker, motion blur, shake, JPEG quality and H.264
  compression (its bit rate on a log scale).

The anchor's score falls nearly monotonically with ``d``, so the study places its trials by
bracketing (:func:`next_difficulty`) and reaches the target within a point in a handful of
trials. A trial is scored exactly as ``crowdsim compare`` scores it (:func:`score`): the
sequence is generated to disk (JPEG and codec included) and tracked from its MOT folder.
Trials run through Optuna's ask-and-tell interface: SIGINT or SIGTERM during a trial marks it
failed and goes on as one ``interrupted`` line (no Optuna traceback); the finished trials stay
in the study.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import re
import sqlite3
import tempfile
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from crowdsim.atomic import (
    holds_only_leftovers,
    new_study_files,
    study_storage,
    write_text_atomic,
)
from crowdsim.knobs import apply_knobs, knob_values, scaled
from tracker.bqp.ablation import ablation_rows

TOLERANCE: float = 1.0
"""A study stops early once the anchor's score is within this many points of the target."""
MAX_TRIALS: int = 200
"""Most trials per sequence (``--trials``); the bracketing needs 3-9."""
STUDY_FILE = "calibration.db"
"""The studies' SQLite file in the output folder (unless ``--study``)."""
RECORD_FILE = "calibrate.json"
"""The output folder's record: the suite calibrated from, every file written (SHA-256), the
results."""
STUDY_ATTR = "crowdsim_calibrate"
"""User attribute marking an Optuna study as made by this module."""
README_MARK = "<!-- written by crowdsim calibrate: rewritten on every run -->"
"""Last line of every README this module writes; a README without it is never replaced."""
OPTUNA_TABLES = frozenset({"studies", "trials", "version_info"})


@dataclass(frozen=True)
class Anchor:
    """What a calibration matches: one tracker configuration and the paper column it must score.

    Attributes
    ----------
    name : str
        ``--anchor`` value.
    label : str
        The paper's row or column, in words.
    tracker, overrides :
        The registered tracker and its parameter overrides that stand for that row.
    key : str
        Spec ``[calibration]`` fields: the target ``paper_<key>_15px`` and the achieved score
        ``achieved_<key>_15px``.
    profile : str
        The difficulty scale's ends (:data:`crowdsim.knobs.PROFILES`).
    """

    name: str
    label: str
    tracker: str
    overrides: dict[str, Any]
    key: str
    profile: str

    @property
    def paper_key(self) -> str:
        return f"paper_{self.key}_15px"

    @property
    def achieved_key(self) -> str:
        return f"achieved_{self.key}_15px"


ANCHORS: dict[str, Anchor] = {
    "b-ncc": Anchor(
        "b-ncc",
        "paper 1's B(NCC) row of Table 3: the BQP tracker with the appearance term only, NCC "
        "appearance (a plain template tracker); static camera",
        "bqp",
        dict(ablation_rows())["B (NCC)"],  # the same configuration as crowdsim ablation's row
        "b_ncc",
        "static",
    ),
    "ncc11": Anchor(
        "ncc11",
        "the papers' NCC column ([11]'s implementation, about 30 points below a plain template "
        "tracker by paper 1's account), matched by the independent NCC tracker; every knob up "
        "to its hard end, camera shake included",
        "ncc",
        {},
        "ncc",
        "hard",
    ),
}
"""The anchors of ``crowdsim calibrate --anchor``. ``b-ncc`` (the default) is paper 1's own
template baseline, the same kind of tracker as ours, with a static camera as in the papers'
footage; ``ncc11`` is the earlier anchor, kept for the ``ucf9-shake`` variant."""
DEFAULT_ANCHOR = "b-ncc"


def anchor_of(name: str) -> Anchor:
    """The anchor called ``name``; ``ValueError`` listing the anchors."""
    from crowdsim.checks import require_choice

    require_choice("", "--anchor", name, tuple(ANCHORS))
    return ANCHORS[name]


def score(spec: Any, workdir: str | os.PathLike[str], anchor: str = DEFAULT_ANCHOR) -> float:
    """acc@15 (%) of ``anchor``'s tracker on ``spec``, generated into ``workdir`` and tracked
    from its MOT folder exactly as ``crowdsim compare`` / ``ablation`` track it."""
    from synth_data.generate import generate
    from synth_data.sequence import open_sequence
    from tracker.registry import make_tracker
    from tracker.runner import run_tracker

    a = anchor_of(anchor)
    generate([spec], workdir, progress=False, overwrite=True, log=lambda m: None)
    tracker = make_tracker(a.tracker, **a.overrides)
    run = run_tracker(tracker, open_sequence(Path(workdir) / spec.name), metrics="accuracy")
    return float(run.report["acc@15"])


def next_difficulty(points: list[tuple[float, float]], target: float) -> float | None:
    """The next difficulty to try, by safeguarded regula falsi on ``(difficulty, score)``.

    The score falls (noisily) as the difficulty rises. The bracket is the hardest tried
    point still above the target and the easiest at or below it; the next point interpolates
    the scores linearly inside it, kept 10 % away from either end so that the bracket always
    shrinks. ``None`` when nothing is left to try (the spec as written is already harder than
    the target, or the bracket is narrower than 1e-3).

    >>> next_difficulty([], 50.0)
    0.0
    >>> next_difficulty([(0.0, 70.0)], 50.0)
    1.0
    >>> round(next_difficulty([(0.0, 70.0), (1.0, 30.0)], 50.0), 3)
    0.5
    >>> next_difficulty([(0.0, 40.0)], 50.0) is None
    True
    """
    if not points:
        return 0.0
    easy = [p for p in points if p[1] > target]
    hard = [p for p in points if p[1] <= target]
    if not easy:
        return None
    lo_d, lo_s = max(easy)
    if not hard:
        return 1.0 if lo_d < 1.0 else None
    hi_d, hi_s = min(hard)
    if hi_d - lo_d < 1e-3:
        return None
    f = (lo_s - target) / max(lo_s - hi_s, 1e-9)
    f = min(max(f, 0.1), 0.9)
    return lo_d + f * (hi_d - lo_d)


def calibrate_spec(
    spec: Any,
    target: float,
    *,
    anchor: str = DEFAULT_ANCHOR,
    trials: int = 12,
    storage: str | None = None,
    log: Callable[[str], None] = print,
) -> dict[str, Any]:
    """Search the difficulty (``scene = camera = d``) so that ``anchor``'s tracker scores
    ``target`` % at 15 px.

    Each trial of an Optuna study (in ``storage``, an Optuna URL: SQLite makes it resumable
    after a kill; an SQLite file is checked first, :func:`check_study_file`) is placed by
    :func:`next_difficulty`, rendered on the anchor's profile of the scale and scored by
    :func:`score`; the study stops once a trial lands within :data:`TOLERANCE` points.
    Returns ``{"anchor", "difficulty", "score_15px", "error", "trials", "values"}`` of the
    trial closest to the target: ``score_15px`` is the score that trial measured, ``error``
    its distance from ``target``.
    """
    import optuna
    from optuna.trial import TrialState

    from crowdsim.checks import require_number

    a = anchor_of(anchor)
    require_number("calibrate_spec", "target", target, lo=0, hi=100)
    require_number("calibrate_spec", "trials", trials, lo=1, hi=MAX_TRIALS, integer=True)
    if storage is not None and storage.startswith("sqlite:///"):
        check_study_file(Path(storage[len("sqlite:///") :]))
    optuna.logging.set_verbosity(optuna.logging.WARNING)
    name = study_name(spec, anchor)
    with new_study_files(storage):  # a half-made database of this run is not left behind
        try:
            study = optuna.create_study(
                study_name=name, storage=storage, direction="minimize", load_if_exists=True
            )
        except Exception as exc:  # SQLAlchemy / Optuna errors of a damaged file
            raise ValueError(
                f"cannot open study {name!r} in {storage}: {type(exc).__name__}: "
                f"{(str(exc).splitlines() or [''])[0]}"
            ) from None
        mark = {
            "sequence": spec.name,
            "digest": spec.digest(),
            "anchor": anchor,
            "tracker": tracker_digest(anchor),
        }
        old = study.user_attrs.get(STUDY_ATTR)
        if old is None:
            if study.trials:
                raise ValueError(
                    f"study {name!r} in {storage} was not made by crowdsim calibrate; choose "
                    "another --study or --out"
                )
            study.set_user_attr(STUDY_ATTR, mark)
        elif old != mark:
            raise ValueError(f"study {name!r} in {storage} was made for another spec ({old})")

    def points() -> list[tuple[float, float]]:
        return [
            (t.params["difficulty"], t.user_attrs["score_15px"])
            for t in study.get_trials(deepcopy=False, states=(TrialState.COMPLETE,))
        ]

    with tempfile.TemporaryDirectory(prefix="crowdsim-calibrate-") as work, study_storage(storage):
        while len(done := points()) < trials:
            if done and min(abs(s - target) for _, s in done) <= TOLERANCE:
                break
            d = next_difficulty(done, target)
            if d is None:
                break
            study.enqueue_trial({"difficulty": d})
            trial = study.ask()
            try:
                d = trial.suggest_float("difficulty", 0.0, 1.0)
                values = knob_values(spec, d, d, a.profile)
                got = float(score(apply_knobs(spec, values), work, anchor))
                if not 0.0 <= got <= 100.0:
                    raise ValueError(
                        f"{spec.name}: the {anchor} score is not a percentage: {got!r}"
                    )
            except BaseException:  # an interrupt included: failed, and no Optuna traceback
                study.tell(trial, state=TrialState.FAIL)
                raise
            trial.set_user_attr("score_15px", got)
            study.tell(trial, abs(got - target))
            log(
                f"{spec.name}: trial {trial.number}: difficulty {d:.3f} -> {anchor} "
                f"{got:.1f}% (target {target:g})"
            )
    done = points()
    if not done:
        raise ValueError(f"{spec.name}: no finished calibration trial in {storage}")
    # the closest to *this* target (a study's values hold the distance to the target of the
    # run that made them; the measured scores do not depend on it)
    d, best = min(done, key=lambda p: (abs(p[1] - target), p[0]))
    return {
        "anchor": anchor,
        "difficulty": round(d, 4),
        "score_15px": round(best, 2),
        "error": round(abs(best - target), 2),
        "trials": len(done),
        "values": knob_values(spec, d, d, a.profile),
    }


def study_name(spec: Any, anchor: str = DEFAULT_ANCHOR) -> str:
    """The study of a spec: the anchor, its name, the digest of its uncalibrated rendering and
    that of the anchor's tracker parameters (:func:`tracker_digest`), so that a changed
    tracker default is a new study, never one whose trials another tracker scored."""
    return f"calibrate-{anchor}-{spec.name}-{spec.digest()[:12]}-{tracker_digest(anchor)}"


def tracker_digest(anchor: str = DEFAULT_ANCHOR) -> str:
    """SHA-256 (12 hex digits) of the complete parameters of ``anchor``'s tracker, as
    ``crowdsim compare`` keys its cells (:func:`crowdsim.lab.experiments.params_digest`)."""
    from crowdsim.lab.experiments import params_digest

    a = anchor_of(anchor)
    return params_digest(a.tracker, a.overrides)


def check_study_file(path: str | os.PathLike[str]) -> None:
    """Refuse a study file that calibrate must not write into, reading it only.

    A missing or empty file is fine (Optuna creates it). Refused, naming the file: a folder,
    a file that is not SQLite, an SQLite database whose tables are not Optuna's, and an Optuna
    database holding a study this module did not make (marked with :data:`STUDY_ATTR`).
    """
    path = Path(path)
    hint = "choose another --study or --out"
    if path.is_dir():
        raise ValueError(f"--study {path}: is a folder, not a study file")
    if not path.exists() or path.stat().st_size == 0:
        return
    with open(path, "rb") as fh:
        head = fh.read(16)
    if head != b"SQLite format 3\x00":
        raise ValueError(f"--study {path}: not an SQLite file (a calibration study is); {hint}")
    try:
        con = sqlite3.connect(f"{path.resolve().as_uri()}?mode=ro", uri=True)
        try:
            tables = {
                r[0] for r in con.execute("SELECT name FROM sqlite_master WHERE type='table'")
            }
            foreign = []
            if OPTUNA_TABLES <= tables:
                foreign = [
                    r[0]
                    for r in con.execute(
                        "SELECT study_name FROM studies s WHERE NOT EXISTS (SELECT 1 FROM "
                        "study_user_attributes a WHERE a.study_id = s.study_id AND a.key = ?)",
                        (STUDY_ATTR,),
                    )
                ]
        finally:
            con.close()
    except sqlite3.Error as exc:
        raise ValueError(f"--study {path}: a damaged SQLite file ({exc}); {hint}") from None
    if tables and not OPTUNA_TABLES <= tables:
        raise ValueError(
            f"--study {path}: an SQLite database that is not an Optuna study (tables "
            f"{', '.join(sorted(tables)[:5])}); {hint}"
        )
    if foreign:
        raise ValueError(
            f"--study {path}: holds the Optuna study {foreign[0]!r}, not made by crowdsim "
            f"calibrate; {hint}"
        )


# ------------------------------------------------------------------------- spec files
def _format(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, str):
        return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(v, float):
        return repr(round(v, 4)) if math.isfinite(v) else "0.0"
    return str(v)


def set_table_values(
    text: str, table: str, values: dict[str, Any], drop: Sequence[str] = ()
) -> str:
    """Set ``key = value`` lines of TOML table ``[table]`` in ``text``, keeping the rest.

    Existing keys are replaced in place (an end-of-line comment is kept), missing keys are
    appended at the end of the table, a missing table is appended to the file; the lines of
    the keys in ``drop`` are removed from the table.

    >>> print(set_table_values('a = 1\\n[x]\\nb = 2  # two\\n[y]\\n', "x", {"b": 3, "c": 0.5}))
    a = 1
    [x]
    b = 3  # two
    c = 0.5
    [y]
    <BLANKLINE>
    """
    lines = text.splitlines()
    header = re.compile(r"^\s*\[([^\]]+)\]\s*(#.*)?$")
    start = next(
        (
            i
            for i, ln in enumerate(lines)
            if (m := header.match(ln)) and m.group(1).strip() == table
        ),
        None,
    )
    if start is None:
        lines += ["", f"[{table}]"] + [f"{k} = {_format(v)}" for k, v in values.items()]
        return "\n".join(lines) + "\n"
    end = next((i for i in range(start + 1, len(lines)) if header.match(lines[i])), len(lines))
    todo = dict(values)
    dropped = []
    for i in range(start + 1, end):
        m = re.match(r"^(\s*)([A-Za-z0-9_]+)(\s*=\s*)([^#]*?)(\s*#.*)?$", lines[i])
        if m and m.group(2) in drop:
            dropped.append(i)
        elif m and m.group(2) in todo:
            lines[i] = (
                f"{m.group(1)}{m.group(2)}{m.group(3)}{_format(todo.pop(m.group(2)))}"
                f"{m.group(5) or ''}"
            )
    for i in reversed(dropped):
        del lines[i]
    end -= len(dropped)
    insert = end
    while insert > start + 1 and not lines[insert - 1].strip():
        insert -= 1
    lines[insert:insert] = [f"{k} = {_format(v)}" for k, v in todo.items()]
    return "\n".join(lines) + "\n"


def calibrated_text(text: str, result: dict[str, Any], source: str = "<spec>") -> str:
    """The spec file ``text`` with the calibrated knobs and the achieved score written in.

    The first time, the knobs' values as written before are kept in ``[calibration]``
    (``base_<section>_<name>``, see :func:`uncalibrated_values`). The new text is validated
    as a spec (a ``ValueError`` naming ``source`` otherwise).
    """
    from synth_data.spec import parse_spec_text, spec_from_dict

    before = spec_from_dict(parse_spec_text(text, "toml", source), source=source)
    if not any(k.startswith("base_") for k in before.calibration):
        app, cam = before.appearance, before.camera
        base = {
            _base_key(s, n): (getattr(app, n) if s == "appearance" else cam.get(n, 0.0))
            for (s, n) in result["values"]
        }
        text = set_table_values(text, "calibration", base)
    for section in ("appearance", "camera"):
        vals = {n: v for (s, n), v in result["values"].items() if s == section}
        text = set_table_values(text, section, vals)
    a = anchor_of(result.get("anchor", DEFAULT_ANCHOR))
    text = set_table_values(
        text,
        "calibration",
        {
            "anchor": a.name,
            "difficulty": result["difficulty"],
            a.achieved_key: result["score_15px"],
            "trials": result["trials"],
            "note": f"knobs set by crowdsim calibrate --anchor {a.name} ({a.tracker} tracker "
            f"{_overrides_text(a)}, acc@15 on the full sequence; {a.profile} profile)",
        },
        # another anchor's achieved score described knobs that are gone
        drop=[b.achieved_key for b in ANCHORS.values() if b is not a],
    )
    spec_from_dict(parse_spec_text(text, "toml", source), source=source)  # never a bad spec
    return text


def _overrides_text(a: Anchor) -> str:
    return ", ".join(f"{k}={v}" for k, v in a.overrides.items()) or "as registered"


def write_calibration(
    path: str | os.PathLike[str], result: dict[str, Any], text: str | None = None
) -> None:
    """Write the calibrated knobs and the achieved score into the spec file at ``path``
    (atomically; see :func:`calibrated_text`), into ``text`` when given (the spec as it was
    calibrated), else into the file as it is now."""
    path = Path(path)
    text = path.read_text() if text is None else text
    write_text_atomic(path, calibrated_text(text, result, str(path)))


# ------------------------------------------------------------------------- suites
def _sha256(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


class OutputFolder:
    """A suite folder this module writes, and the record (:data:`RECORD_FILE`) proving which
    of its files it wrote: ``{"format": 1, "written_by": "crowdsim calibrate", "source": ...,
    "files": {name: [sha256, ...]}, "results": {sequence: {...}}}``.

    A file is replaced only when its content matches a recorded checksum (while a write is
    under way, both the old and the new one are recorded, so a kill between the two steps
    leaves a folder the next run still accepts).
    """

    def __init__(self, path: Path, source: str) -> None:
        self.path = path
        self.source = source
        self.record = self._read()

    def _read(self) -> dict[str, Any]:
        path = self.path / RECORD_FILE
        fresh = {
            "format": 1,
            "written_by": "crowdsim calibrate",
            "source": self.source,
            "files": {},
            "results": {},
        }
        if self.path.exists() and not self.path.is_dir():
            raise ValueError(f"--out {self.path}: is a file, not a folder")
        if not path.exists():
            if self.path.is_dir() and not holds_only_leftovers(self.path):
                raise ValueError(
                    f"--out {self.path}: not empty and not written by crowdsim calibrate (no "
                    f"{RECORD_FILE}); choose a new folder"
                )
            return fresh
        try:
            data = json.loads(path.read_bytes())
        except ValueError as exc:
            raise ValueError(
                f"{path}: damaged ({str(exc).splitlines()[0]}); choose a new --out"
            ) from None
        ok = (
            isinstance(data, dict)
            and data.get("written_by") == "crowdsim calibrate"
            and isinstance(data.get("files"), dict)
            and isinstance(data.get("results"), dict)
            and all(
                isinstance(v, list) and all(isinstance(h, str) for h in v)
                for v in data["files"].values()
            )
        )
        if not ok:
            raise ValueError(f"{path}: not a crowdsim calibrate record; choose a new --out")
        if data.get("source") != self.source:
            raise ValueError(
                f"--out {self.path}: holds a calibration of the suite {data.get('source')!r}, "
                f"not {self.source!r}; choose another --out"
            )
        return data

    def check_owned(self, name: str) -> None:
        """Refuse to replace ``name`` unless it is missing or unchanged since we wrote it."""
        path = self.path / name
        if not path.exists() and not path.is_symlink():
            return
        if path.is_file() and not path.is_symlink():
            if _sha256(path.read_bytes()) in self.record["files"].get(name, []):
                return
        raise ValueError(
            f"{path}: not written by crowdsim calibrate, or changed since; move it away or "
            "choose another --out"
        )

    def write(self, name: str, data: bytes) -> None:
        """Write file ``name`` atomically, recording its checksum first and last."""
        from crowdsim.atomic import atomic_path

        self.check_owned(name)
        self.path.mkdir(parents=True, exist_ok=True)
        new = _sha256(data)
        self.record["files"][name] = sorted({*self.record["files"].get(name, []), new})
        self.save()
        with atomic_path(self.path / name) as tmp:
            tmp.write_bytes(data)
        self.record["files"][name] = [new]
        self.save()

    def save(self) -> None:
        self.path.mkdir(parents=True, exist_ok=True)
        write_text_atomic(self.path / RECORD_FILE, json.dumps(self.record, indent=1) + "\n")


def calibrate_suite(
    suite: str | os.PathLike[str],
    *,
    out: str | os.PathLike[str],
    only: Sequence[str] | None = None,
    anchor: str = DEFAULT_ANCHOR,
    trials: int = 12,
    study: str | os.PathLike[str] | None = None,
    update_suite: bool = False,
    force: bool = False,
    log: Callable[[str], None] = print,
) -> dict[str, dict[str, Any]]:
    """Calibrate every sequence of ``suite`` with a paper figure for ``anchor`` (its spec's
    ``[calibration] paper_<key>_15px``, :data:`ANCHORS`) into the folder ``out``.

    Parameters
    ----------
    suite : str or path
        A built-in suite name or a suite folder (:func:`synth_data.suites.suite_dir`).
    out : path
        The calibrated suite folder (module docstring): new, empty, or written by an earlier
        run of this function on the same suite (which it resumes).
    only : list of str, optional
        Calibrate only these sequences (the other specs are copied as they are).
    anchor : str
        ``"b-ncc"`` (paper 1's B(NCC) row, static-camera profile) or ``"ncc11"`` (the papers'
        NCC column, every knob to its hard end); see :data:`ANCHORS`.
    trials : int
        Trials per sequence at most (1 .. :data:`MAX_TRIALS`).
    study : path, optional
        The studies' SQLite file (default ``out/calibration.db``); checked by
        :func:`check_study_file`.
    update_suite : bool
        Also write each new calibration into the suite's own spec file, unless the spec
        records a calibration closer to the paper's figure (``force`` writes it anyway) or
        the file changed since this run read it (kept as it is, said in the log).

    Returns ``{sequence: {"paper_15px", "anchor", "difficulty", "score_15px", "error",
    "trials", "suite_spec"}}``; ``suite_spec`` is ``"updated"``, ``"kept"`` or ``None`` (no
    ``update_suite``). Every input is checked before anything is written.
    """
    from crowdsim.checks import require_number, require_output_dir
    from synth_data.suites import PAPER_FILE, SUITE_NAMES, suite_dir, suite_files, suite_specs

    a = anchor_of(anchor)
    require_number("", "--trials", trials, lo=1, hi=MAX_TRIALS, integer=True)
    if force and not update_suite:
        raise ValueError("--force needs --update-suite (it lets a worse calibration replace it)")
    if isinstance(only, str):
        only = [only]
    source_dir = suite_dir(suite)
    files = suite_files(suite)
    listed = suite_specs(suite, list(only) if only else None)
    specs = [s for s in listed if a.paper_key in s.calibration]
    if only and specs and len(specs) < len(listed):  # named, so never skipped in silence
        lacking = [s.name for s in listed if a.paper_key not in s.calibration]
        raise ValueError(
            f"--only {', '.join(lacking)}: no [calibration] {a.paper_key}, the target of "
            f"--anchor {anchor}, in suite {str(suite)!r}"
        )
    if not specs:
        others = [
            b.name for b in ANCHORS.values() if any(b.paper_key in s.calibration for s in listed)
        ]
        hint = f" (it has figures for --anchor {', '.join(others)})" if others else ""
        raise ValueError(
            f"suite {str(suite)!r}: no spec records [calibration] {a.paper_key}, the target "
            f"of --anchor {anchor}{hint}"
        )
    for s in specs:
        for key in (a.paper_key, a.achieved_key):
            if key in s.calibration:
                require_number(f"{s.source}: calibration", key, s.calibration[key], lo=0, hi=100)
        _uncalibrated(s)  # its recorded base_* values, checked before the first write
    out = Path(out)
    if out.resolve() == source_dir.resolve():
        raise ValueError(
            f"--out {out}: is the suite folder itself; calibrate writes a new suite folder "
            "(add --update-suite to change the suite as well)"
        )
    require_output_dir("--out", out, writable=True)  # read-only: refused up front
    where = source_dir.resolve()  # a built-in suite by name, also when given as its folder
    source = next((n for n in SUITE_NAMES if suite_dir(n).resolve() == where), str(where))
    folder = OutputFolder(out, source)
    paper = source_dir / PAPER_FILE
    replaced = [Path(s.source).name for s in specs] + ["README.md"]
    for name in replaced + ([PAPER_FILE] if paper.is_file() else []):
        folder.check_owned(name)  # the other specs are only copied where missing
    study_path = Path(study) if study is not None else out / STUDY_FILE
    if study is not None:
        if str(study).startswith("sqlite:///"):
            study_path = Path(str(study)[len("sqlite:///") :])
        elif "://" in str(study) or str(study).startswith("journal:"):
            raise ValueError(f"--study must be an SQLite file (a path), got {str(study)!r}")
        if not study_path.parent.is_dir():
            raise ValueError(f"--study {study_path}: no such folder {study_path.parent}")
        require_output_dir("--study", study_path)  # SQLite writes beside it
    check_study_file(study_path)
    if update_suite:
        for s in specs:
            if not os.access(s.source, os.W_OK) or not os.access(source_dir, os.W_OK):
                raise ValueError(f"--update-suite: cannot write {s.source} (read-only)")

    # the texts calibrated: a spec edited while the run goes on is not mixed with its results
    texts = {s.name: Path(s.source).read_text() for s in specs}

    # every check passed: write
    for f in files:  # a complete suite folder: the specs not calibrated now, as they are
        if not (out / f.name).exists():
            folder.write(f.name, f.read_bytes())
    if paper.is_file():
        folder.write(PAPER_FILE, paper.read_bytes())
    storage = f"sqlite:///{study_path.resolve()}"
    label = str(suite)
    results: dict[str, dict[str, Any]] = {}
    updated = False
    try:
        for spec in specs:
            target = float(spec.calibration[a.paper_key])
            # search from the uncalibrated knobs, so a rerun searches the same space
            res = calibrate_spec(
                _uncalibrated(spec),
                target,
                anchor=anchor,
                trials=trials,
                storage=storage,
                log=log,
            )
            name = Path(spec.source).name
            text = calibrated_text(texts[spec.name], res, str(out / name))
            folder.write(name, text.encode())
            verdict = None
            if update_suite:
                verdict = _update_suite_spec(spec, texts[spec.name], target, res, force, log)
                updated = updated or verdict == "updated"
            log(
                f"{spec.name}: {anchor} {res['score_15px']:.1f}% (paper {target:g}%), difficulty "
                f"{res['difficulty']:.3f}, {res['trials']} trials -> {out / name}"
            )
            results[spec.name] = {
                "paper_15px": target,
                **{k: v for k, v in res.items() if k != "values"},
                "suite_spec": verdict,
            }
            folder.record["results"][spec.name] = results[spec.name]
            folder.write("README.md", suite_readme(out, f"{label} --out {out}").encode())
    except KeyboardInterrupt as exc:
        if not getattr(exc, "detail", ""):
            exc.detail = (
                f"the sequences calibrated so far are written to {out}; the study "
                f"{study_path} keeps the finished trials: rerun the same command to resume"
            )
        raise
    finally:
        if updated:
            _write_source_readme(suite, log)
    return results


def _update_suite_spec(
    spec: Any,
    text: str,
    target: float,
    res: dict[str, Any],
    force: bool,
    log: Callable[[str], None],
) -> str:
    """Write ``res`` into the suite's own spec unless it records a closer calibration against
    the same anchor (a calibration against another anchor is not comparable: replaced), or
    its file is no longer ``text``, the spec calibrated (edited meanwhile: kept as it is)."""
    a = anchor_of(res["anchor"])
    path = Path(spec.source)
    if path.read_text() != text:
        log(
            f"{spec.name}: kept {spec.source} as it is: it changed since this run read it, so "
            "this calibration is not of it (rerun to calibrate it)"
        )
        return "kept"
    old = spec.calibration.get(a.achieved_key)
    new_err = abs(res["score_15px"] - target)
    if old is not None and not force and new_err > abs(float(old) - target):
        log(
            f"{spec.name}: kept the suite's calibration in {spec.source}: {a.name} "
            f"{float(old):g}% is {abs(float(old) - target):.2f} from the paper's {target:g}%, "
            f"this run's {res['score_15px']:g}% is {new_err:.2f} from it (--force replaces it)"
        )
        return "kept"
    write_calibration(path, res, text)
    log(f"{spec.name}: updated {spec.source} ({a.name} {res['score_15px']:g}%, paper {target:g}%)")
    return "updated"


def _write_source_readme(suite: str | os.PathLike[str], log: Callable[[str], None]) -> None:
    from synth_data.suites import suite_dir

    path = suite_dir(suite) / "README.md"
    if path.exists() and README_MARK not in path.read_text(errors="replace"):
        log(f"{path}: not written by crowdsim calibrate; left unchanged")
        return
    write_text_atomic(path, suite_readme(suite, str(suite)))


def _base_key(section: str, name: str) -> str:
    return f"base_{section}_{name}"


def uncalibrated_values(spec: Any) -> dict[tuple[str, str], Any]:
    """``{(section, name): value}`` of the knobs before the spec's first calibration.

    The first calibration records them in ``[calibration]`` as ``base_<section>_<name>``, so
    a later run searches the same space from the same start (re-running is reproducible, and
    it can make a sequence easier again). Empty for a spec never calibrated. A recorded value
    outside its knob's range (NaN, a string, 400 for noise) is refused naming the spec file
    and the field, and so is a ``base_`` key of no knob (a misspelt one would have left its
    knob's search to start from the spec's calibrated value, in silence).
    """
    from crowdsim.checks import require_number

    where = f"{spec.source}: calibration" if spec.source else "calibration"
    known = {_base_key(k.section, k.name) for k in scaled()}
    for key in spec.calibration:
        if key.startswith("base_") and key not in known:
            raise ValueError(
                f"{where}.{key} records no difficulty knob's value (base_<section>_<knob>, "
                f"one of: {', '.join(sorted(known))})"
            )
    values = {}
    for k in scaled():
        key = _base_key(k.section, k.name)
        if key in spec.calibration:
            v = spec.calibration[key]
            hi = k.hi if math.isfinite(k.hi) else None
            require_number(where, key, v, lo=k.lo, hi=hi, lo_open=k.lo_open, integer=k.integer)
            if 0 < v < k.off_below:
                raise ValueError(
                    f"{where}.{key} must be 0 (off) or at least {k.off_below:g}, got {v!r}"
                )
            values[(k.section, k.name)] = int(v) if k.integer else float(v)
    return values


def _uncalibrated(spec: Any) -> Any:
    """The spec with the knob values it had before its first calibration."""
    values = uncalibrated_values(spec)
    return apply_knobs(spec, values) if values else spec


def suite_readme(suite: str | os.PathLike[str], command: str) -> str:
    """A suite's ``README.md``: the paper's figures beside the achieved ones.

    ``command`` is what follows ``crowdsim calibrate --suite`` in the text (how the figures
    were made)."""
    from synth_data.suites import suite_dir, suite_specs

    rows = [
        "| sequence | scene | people | template px | anchor | paper @15 | calibrated @15 |"
        " difficulty |",
        "|---|---|---|---|---|---|---|---|",
    ]
    anchors = set()
    for s in suite_specs(suite):
        c = s.calibration
        a = ANCHORS.get(str(c.get("anchor", "ncc11")), ANCHORS["ncc11"])
        if a.paper_key in c:
            anchors.add(a.name)
        got = c.get(a.achieved_key)
        rows.append(
            f"| {s.name} | {s.scenario.get('name', '')} | "
            f"{s.scenario.get('n_agents', '')} | {s.appearance.template_px} | {a.name} | "
            f"{c.get(a.paper_key, '')} | {'' if got is None else got} | "
            f"{c.get('difficulty', '')} |"
        )
    name = str(suite) if isinstance(suite, str) and "/" not in suite else suite_dir(suite).name
    return (
        f"# Suite `{name}`\n\nCounterparts of the papers' sequences. `crowdsim calibrate "
        f"--suite {command}` sets each spec's appearance and camera knobs (never its motion) "
        "so that the anchor's tracker scores the paper's figure at 15 px; the achieved "
        "figures below are written by that command, measured on the full sequence as "
        "`crowdsim compare` measures them.\n\n"
        + "".join(f"- `{n}`: {ANCHORS[n].label}.\n" for n in sorted(anchors))
        + ("\n" if anchors else "")
        + "\n".join(rows)
        + f"\n\n{README_MARK}\n"
    )


def write_suite_readme(suite: str | os.PathLike[str]) -> Path:
    """Rewrite ``<suite folder>/README.md`` (:func:`suite_readme`); returns its path."""
    from synth_data.suites import suite_dir

    path = suite_dir(suite) / "README.md"
    write_text_atomic(path, suite_readme(suite, str(suite)))
    return path
