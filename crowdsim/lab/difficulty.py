"""Which difficulty costs which tracker: ``crowdsim difficulty``.

The calibration (:mod:`crowdsim.lab.calibration`) moves all appearance and camera knobs of a
sequence together until the NCC tracker scores the paper's figure. It says nothing about which
of them makes a tracker fail. :func:`attribute` answers that: for each sequence it generates
the calibrated spec, the spec with one *group* of knobs (:data:`DIFFICULTY_GROUPS`) put back to
its uncalibrated value, for every group in turn, and the fully uncalibrated spec, then tracks
all of them with each tracker (:func:`crowdsim.lab.experiments.run_table`: resumable, parallel).
The accuracy a tracker regains when a group is removed is what that group costs it.
"""

from __future__ import annotations

import os
import re
from collections.abc import Callable, Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

from crowdsim.atomic import write_text_atomic
from crowdsim.knobs import apply_knobs, difficulty_groups

DIFFICULTY_GROUPS: dict[str, tuple[str, ...]] = difficulty_groups()
"""Knob groups (spec field names) of the calibration's difficulty scale, read from the ``group``
column of :data:`crowdsim.knobs.KNOBS`: look-alike heads, packed bodies, appearance change
(gait, arm swing, head turns), clutter and moving shadows, sensor noise with JPEG / H.264
compression, defocus and motion blur, illumination flicker, camera shake."""

DEFAULT_TRACKERS: tuple[str, ...] = ("ncc", "pnmc", "bqp")


def _slug(group: str) -> str:
    return re.sub(r"[^a-z0-9]+", "-", group.lower()).strip("-")


def variant_specs(spec: Any) -> list[tuple[str, Any]]:
    """``[(variant, spec)]``: ``calibrated``, ``-<group>`` for every group, ``uncalibrated``.

    A variant's spec is named ``<sequence>.<variant>``; only its appearance and camera knobs
    differ (same seed, same crowd, same motion). Raises ``ValueError`` for a spec that was
    never calibrated (no ``base_*`` values recorded in ``[calibration]``).
    """
    from crowdsim.lab.calibration import uncalibrated_values

    base = uncalibrated_values(spec)
    if not base:
        raise ValueError(
            f"{spec.name}: not calibrated (no base_* values in [calibration]); "
            "run crowdsim calibrate first"
        )
    section = {name: sec for sec, name in base}
    out = [("calibrated", replace(spec, name=f"{spec.name}.calibrated"))]
    for group, names in DIFFICULTY_GROUPS.items():
        values = {(section[n], n): base[(section[n], n)] for n in names}
        v = apply_knobs(spec, values)
        out.append((f"-{group}", replace(v, name=f"{spec.name}.no-{_slug(group)}")))
    out.append(("uncalibrated", replace(apply_knobs(spec, base), name=f"{spec.name}.base")))
    return out


def attribute(
    suite: str | os.PathLike[str],
    out: str | os.PathLike[str],
    *,
    only: Sequence[str] | None = None,
    trackers: Sequence[str] = DEFAULT_TRACKERS,
    frames: int | None = None,
    workers: int = 1,
    backend: str = "local",
    address: str | None = None,
    progress: bool = True,
    log: Callable[[str], None] = print,
) -> dict[str, Any]:
    """Track every difficulty variant of the suite's calibrated sequences with ``trackers``.

    ``suite`` is a built-in name or a suite folder (e.g. one written by ``crowdsim calibrate
    --out``).

    Writes the full table of :func:`crowdsim.lab.experiments.run_table` (``OUT/table.md``,
    ``table.csv``, ``cells.json``, curves) and ``OUT/attribution.md`` / ``.json``: per
    sequence and tracker, acc@15 calibrated, the points regained by removing each group, and
    acc@15 uncalibrated. Returns the attribution document.
    """
    import json

    from crowdsim.lab.experiments import CELLS_FILE, Row, cell_key, read_cells, run_table
    from synth_data.suites import suite_specs
    from tracker.registry import get

    if isinstance(trackers, str):
        trackers = (trackers,)  # one name, not its letters
    rows = []
    for name in trackers:
        get(name)  # an unknown name fails before any work
        rows.append(Row(name, name))
    if not rows:
        raise ValueError("--trackers: name at least one tracker")
    if len(set(trackers)) != len(trackers):
        raise ValueError(f"--trackers: {', '.join(trackers)} names a tracker twice")
    specs = [s for s in suite_specs(suite, list(only) if only else None) if s.calibration]
    if not specs:
        raise ValueError(f"suite {str(suite)!r}: no calibrated sequence to attribute")
    variants = {s.name: variant_specs(s) for s in specs}
    all_specs = [v for vs in variants.values() for _, v in vs]
    run_table(
        rows,
        all_specs,
        out,
        frames=frames,
        workers=workers,
        backend=backend,
        address=address,
        progress=progress,
        title=f"difficulty attribution on {suite}",
        log=log,
    )
    cells = read_cells(Path(out) / CELLS_FILE)  # checked: figures as the trackers measured
    doc: dict[str, Any] = {"suite": str(suite), "groups": DIFFICULTY_GROUPS, "sequences": {}}
    for seq, vs in variants.items():
        per = {}
        for row in rows:
            acc = {
                label: float(cells[cell_key(sp.name, row, frames)]["acc@15"]) for label, sp in vs
            }
            per[row.tracker] = {
                "calibrated": acc["calibrated"],
                "uncalibrated": acc["uncalibrated"],
                "regained": {g: acc[f"-{g}"] - acc["calibrated"] for g in DIFFICULTY_GROUPS},
            }
        doc["sequences"][seq] = per
    out = Path(out)
    write_text_atomic(out / "attribution.json", json.dumps(doc, indent=2) + "\n")
    write_text_atomic(out / "attribution.md", attribution_table(doc))
    return doc


def attribution_table(doc: dict[str, Any]) -> str:
    """Markdown: per sequence and tracker, acc@15 calibrated, the points each group costs
    (acc@15 with the group removed minus calibrated) and acc@15 uncalibrated."""
    groups = list(doc["groups"])
    head = ["sequence", "tracker", "calibrated", *[f"-{g}" for g in groups], "uncalibrated"]
    lines = [
        f"# Difficulty attribution on {doc['suite']} (acc@15 %, and points regained)",
        "",
        "| " + " | ".join(head) + " |",
        "|" + "---|" * len(head),
    ]
    for seq, per in doc["sequences"].items():
        for trk, r in per.items():
            cells = [f"{r['regained'][g]:+.1f}" for g in groups]
            lines.append(
                f"| {seq} | {trk} | {r['calibrated']:.1f} | "
                + " | ".join(cells)
                + f" | {r['uncalibrated']:.1f} |"
            )
    return "\n".join(lines) + "\n"
