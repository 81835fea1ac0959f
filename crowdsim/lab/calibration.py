"""Calibrate a suite's difficulty against the papers: ``crowdsim calibrate``.

The generated crowds must be as hard as the papers' real ones. For every sequence of a suite
whose spec records the paper's NCC score (``[calibration] paper_ncc_15px``), an Optuna study
searches the sequence's *appearance and camera* knobs -- never its motion -- until the
independent NCC tracker's accuracy at 15 px lands on the paper's figure. The knobs are
written back into the spec file (comments and the rest of the file kept), with the achieved
score, so ``crowdsim generate`` reproduces the calibrated sequence exactly.

Search space: one difficulty ``d`` in [0, 1] moving the knobs of both calibration axes of
:data:`crowdsim.knobs.KNOBS` from the spec's own values (0) to their hard ends (1)
(:func:`crowdsim.knobs.knob_values`):

* ``scene`` -- look-alike heads and clothing, packed bodies, gait, arm swing and head turns,
  clutter and moving shadows;
* ``camera`` -- sensor noise, defocus, flicker, motion blur, shake, JPEG quality and H.264
  compression (its bit rate on a log scale).

The NCC score falls nearly monotonically with ``d``, so the study places its trials by
bracketing (:func:`next_difficulty`) and reaches the target within a point in a handful of
trials. A trial is scored exactly as ``crowdsim compare`` scores it: the sequence is
generated to disk (JPEG and codec included) and tracked from its MOT folder.
"""

from __future__ import annotations

import math
import os
import re
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

from crowdsim.atomic import write_text_atomic
from crowdsim.knobs import apply_knobs, knob_values, scaled

TOLERANCE: float = 1.0
"""A study stops early once the NCC score is within this many points of the target."""


def ncc_score(spec: Any, workdir: str | os.PathLike[str]) -> float:
    """acc@15 (%) of the independent NCC tracker on ``spec``, generated into ``workdir``."""
    from synth_data.generate import generate
    from synth_data.sequence import open_sequence
    from tracker.runner import run_tracker

    generate([spec], workdir, progress=False, overwrite=True, log=lambda m: None)
    run = run_tracker("ncc", open_sequence(Path(workdir) / spec.name), metrics="accuracy")
    return float(run.report["acc@15"])


def next_difficulty(points: list[tuple[float, float]], target: float) -> float | None:
    """The next difficulty to try, by safeguarded regula falsi on ``(difficulty, score)``.

    The NCC score falls (noisily) as the difficulty rises. The bracket is the hardest tried
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
    trials: int = 12,
    storage: str | None = None,
    log: Callable[[str], None] = print,
) -> dict[str, Any]:
    """Search the difficulty (``scene = camera = d``) so that NCC scores ``target`` % at 15 px.

    Each trial of an Optuna study (in ``storage``, an Optuna URL: SQLite makes it resumable
    after a kill) is placed by :func:`next_difficulty`; the study stops once a trial lands
    within :data:`TOLERANCE` points. Returns ``{"difficulty", "ncc_15px", "error", "trials",
    "values"}`` of the best trial.
    """
    import optuna

    optuna.logging.set_verbosity(optuna.logging.WARNING)
    study = optuna.create_study(
        study_name=f"calibrate-{spec.name}-{spec.digest()[:12]}",
        storage=storage,
        direction="minimize",
        load_if_exists=True,
    )

    def points() -> list[tuple[float, float]]:
        return [
            (t.params["difficulty"], t.user_attrs["ncc_15px"])
            for t in study.trials
            if t.state == optuna.trial.TrialState.COMPLETE
        ]

    with tempfile.TemporaryDirectory(prefix="crowdsim-calibrate-") as work:

        def objective(trial: Any) -> float:
            d = trial.suggest_float("difficulty", 0.0, 1.0)
            score = ncc_score(apply_knobs(spec, knob_values(spec, d, d)), work)
            trial.set_user_attr("ncc_15px", score)
            log(
                f"{spec.name}: trial {trial.number}: difficulty {d:.3f} -> NCC "
                f"{score:.1f}% (target {target:g})"
            )
            return abs(score - target)

        while len(points()) < trials:
            done = points()
            if done and min(abs(s - target) for _, s in done) <= TOLERANCE:
                break
            d = next_difficulty(done, target)
            if d is None:
                break
            study.enqueue_trial({"difficulty": d})
            study.optimize(objective, n_trials=1)
    best = study.best_trial
    d = best.params["difficulty"]
    return {
        "difficulty": round(d, 4),
        "ncc_15px": round(best.user_attrs["ncc_15px"], 2),
        "error": round(best.value, 2),
        "trials": len(points()),
        "values": knob_values(spec, d, d),
    }


# ------------------------------------------------------------------------- spec files
def _format(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, str):
        return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(v, float):
        return repr(round(v, 4)) if math.isfinite(v) else "0.0"
    return str(v)


def set_table_values(text: str, table: str, values: dict[str, Any]) -> str:
    """Set ``key = value`` lines of TOML table ``[table]`` in ``text``, keeping the rest.

    Existing keys are replaced in place (an end-of-line comment is kept), missing keys are
    appended at the end of the table, a missing table is appended to the file.

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
    for i in range(start + 1, end):
        m = re.match(r"^(\s*)([A-Za-z0-9_]+)(\s*=\s*)([^#]*?)(\s*#.*)?$", lines[i])
        if m and m.group(2) in todo:
            lines[i] = (
                f"{m.group(1)}{m.group(2)}{m.group(3)}{_format(todo.pop(m.group(2)))}"
                f"{m.group(5) or ''}"
            )
    insert = end
    while insert > start + 1 and not lines[insert - 1].strip():
        insert -= 1
    lines[insert:insert] = [f"{k} = {_format(v)}" for k, v in todo.items()]
    return "\n".join(lines) + "\n"


def write_calibration(path: str | os.PathLike[str], result: dict[str, Any]) -> None:
    """Write the calibrated knobs and the achieved score into the spec file at ``path``.

    The first time, the knobs' values as written before are kept in ``[calibration]``
    (``base_<section>_<name>``), see :func:`_uncalibrated`.
    """
    from synth_data.spec import load_spec

    path = Path(path)
    text = path.read_text()
    before = load_spec(path)
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
    text = set_table_values(
        text,
        "calibration",
        {
            "difficulty": result["difficulty"],
            "achieved_ncc_15px": result["ncc_15px"],
            "trials": result["trials"],
            "note": "knobs set by crowdsim calibrate (NCC tracker, acc@15 on the full sequence)",
        },
    )
    tmp = path.with_name(f".{path.stem}.calibrate{path.suffix}")
    tmp.write_text(text)
    try:
        load_spec(tmp)  # never write a spec that does not load
    finally:
        tmp.unlink()
    write_text_atomic(path, text)


def calibrate_suite(
    suite: str,
    *,
    only: list[str] | None = None,
    trials: int = 12,
    out: str | os.PathLike[str] | None = None,
    log: Callable[[str], None] = print,
) -> dict[str, dict[str, Any]]:
    """Calibrate every sequence of ``suite`` with a paper NCC figure; write specs and README.

    Studies are kept in ``out/calibration.db`` (SQLite; a killed run resumes where it was).
    """
    from crowdsim.checks import require_number
    from synth_data.suites import suite_dir, suite_specs

    require_number("", "--trials", trials, lo=1, integer=True)
    specs = [s for s in suite_specs(suite, only) if "paper_ncc_15px" in s.calibration]
    if not specs:
        raise ValueError(f"suite {suite!r}: no spec records [calibration] paper_ncc_15px")
    out = Path(out) if out is not None else Path(tempfile.mkdtemp(prefix="crowdsim-calib-"))
    out.mkdir(parents=True, exist_ok=True)
    storage = f"sqlite:///{(out / 'calibration.db').resolve()}"
    results = {}
    for spec in specs:
        target = float(spec.calibration["paper_ncc_15px"])
        # search from the uncalibrated knobs, so a rerun searches the same space
        base = _uncalibrated(spec)
        res = calibrate_spec(base, target, trials=trials, storage=storage, log=log)
        write_calibration(spec.source or suite_dir(suite) / f"{spec.name}.toml", res)
        log(
            f"{spec.name}: NCC {res['ncc_15px']:.1f}% (paper {target:g}%), difficulty "
            f"{res['difficulty']:.3f}, {res['trials']} trials"
        )
        results[spec.name] = {
            "paper_ncc_15px": target,
            **{k: v for k, v in res.items() if k != "values"},
        }
    write_suite_readme(suite)
    return results


def _base_key(section: str, name: str) -> str:
    return f"base_{section}_{name}"


def uncalibrated_values(spec: Any) -> dict[tuple[str, str], Any]:
    """``{(section, name): value}`` of the knobs before the spec's first calibration.

    The first calibration records them in ``[calibration]`` as ``base_<section>_<name>``, so
    a later run searches the same space from the same start (re-running is reproducible, and
    it can make a sequence easier again). Empty for a spec never calibrated.
    """
    values = {}
    for k in scaled():
        key = _base_key(k.section, k.name)
        if key in spec.calibration:
            v = spec.calibration[key]
            values[(k.section, k.name)] = int(v) if k.integer else float(v)
    return values


def _uncalibrated(spec: Any) -> Any:
    """The spec with the knob values it had before its first calibration."""
    values = uncalibrated_values(spec)
    return apply_knobs(spec, values) if values else spec


def write_suite_readme(suite: str) -> Path:
    """``synth_data/suites/<suite>/README.md``: the paper's NCC figures beside the achieved."""
    from synth_data.suites import suite_dir, suite_specs

    rows = [
        "| sequence | scene | people | template px | paper NCC @15 | calibrated NCC @15 |"
        " difficulty |",
        "|---|---|---|---|---|---|---|",
    ]
    for s in suite_specs(suite):
        c = s.calibration
        got = c.get("achieved_ncc_15px")
        rows.append(
            f"| {s.name} | {s.scenario.get('name', '')} | "
            f"{s.scenario.get('n_agents', '')} | {s.appearance.template_px} | "
            f"{c.get('paper_ncc_15px', '')} | {'' if got is None else got} | "
            f"{c.get('difficulty', '')} |"
        )
    text = (
        f"# Suite `{suite}`\n\nCounterparts of the papers' sequences. `crowdsim calibrate "
        f"--suite {suite}` sets each spec's appearance and camera knobs (never its motion) "
        "so that the independent NCC tracker scores the paper's NCC figure at 15 px; the "
        "achieved figures below are written by that command, measured on the full "
        "sequence as `crowdsim compare` measures them.\n\n" + "\n".join(rows) + "\n"
    )
    path = suite_dir(suite) / "README.md"
    write_text_atomic(path, text)
    return path
