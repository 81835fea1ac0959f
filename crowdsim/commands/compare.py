"""``crowdsim compare``: every tracker on a suite or your sequences, beside the papers' figures.

``crowdsim compare --suite NAME|DIR | --sequences DIR [--only SEQ ...] [--trackers NAME ...]
[--cmc] [--params FILE ...] [--set NAME=VALUE ...] [--frames N] [--workers N]
[--backend local|ray [--address ADDR]] --out DIR``

``--suite`` is a built-in suite (ucf9, ucf9-shake, ucf9-drone, galleria, stress) or a suite
folder of spec files, such as the one ``crowdsim calibrate --out`` writes (its ``paper.json``
gives the papers' column). ``--sequences DIR`` runs the same rows on sequences you already
have in the MOT layout instead (a folder of sequence folders, or one: ``seqinfo.ini``,
``gt/gt.txt``, ``img1/`` frames or ``video.mp4``, as ``generate`` writes them or as
MOTChallenge footage comes), read as ``track`` reads them and never written into; the table
says the papers report nothing on them, and ``--frames N`` tracks their first N frames.
Rows: NCC, mean-shift, PNMC, BQP (KCF), BQP (NCC appearance), ByteTrack and OC-SORT at
detector miss rates 0.1 and 0.3; with ``--cmc``, each detection-free tracker also with
camera-motion compensation (``<row> + CMC``); ``--trackers`` keeps only the rows of those
registered trackers; ``--params FILE ...`` adds a row per tuned parameter file (the tracker it
names, with its parameters); ``--set NAME=VALUE`` gives every row whose tracker has that parameter
its value (``--set fw_variant=block``: both BQP rows with the block solver). Per sequence:
acc@15, acc@5, MOTA, IDF1, HOTA, frames/s. Writes ``table.md``, ``table.csv`` and
accuracy-versus-threshold PNGs and prints the table.
Resumable: a rerun with the same ``--out`` skips finished cells, each checked against the
checksum stored with it in ``cells.json`` (an edited cell is refused, naming it; see
:mod:`crowdsim.lab.experiments`). A cell of ``--sequences`` is keyed by a digest of its
sequence's ground truth, ``seqinfo.ini`` and frame files
(:func:`crowdsim.lab.experiments.sequence_digest`): an edited sequence is a new cell. A
sequence folder in ``DIR/sequences`` made from another spec is never replaced (exit 2: remove
it or choose another ``--out``), nor is a ``table.md``, ``table.csv`` or curve that no table
run wrote (``outputs.json`` lists the digests of what one did).
"""

from __future__ import annotations

import argparse

from crowdsim.commands._table_args import (
    add_set_argument,
    add_table_arguments,
    run_table_command,
    table_source,
)


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "compare",
        help="compare every tracker on a suite (the papers' Table 1)",
        description=__doc__.splitlines()[0].replace("``", ""),
    )
    add_table_arguments(p, sequences=True)
    add_set_argument(p)
    p.add_argument(
        "--cmc",
        action="store_true",
        help="add each detection-free tracker (NCC, mean-shift, PNMC, BQP) with camera-motion "
        "compensation as a '+ CMC' row",
    )
    p.add_argument(
        "--trackers",
        nargs="+",
        metavar="NAME",
        help="only the rows that run these trackers: ncc, meanshift, pnmc, bqp, bqp-ncc, "
        "bytetrack, ocsort; any other registered tracker (bqp-dense, one of your own) gets a "
        "row under its name (default: every row)",
    )
    p.add_argument(
        "--params",
        nargs="+",
        metavar="FILE",
        help="add a row for each tuned parameter file (best_params.json of crowdsim tune, or "
        "any file track --params takes): the tracker it names with those parameters, "
        "labelled 'NAME tuned (FILE)'",
    )
    p.set_defaults(func=run)


def tuned_rows(files: list[str]) -> tuple:
    """One :class:`~crowdsim.lab.experiments.Row` per parameter file: the tracker the file
    names, overriding the fields whose values differ from its defaults (so ``--set`` of one
    of them is refused as the row's own)."""
    from dataclasses import fields
    from pathlib import Path

    from crowdsim.lab.experiments import Row
    from envs.param_space import load_params
    from synth_data.detections import DetectionParams
    from tracker.registry import get

    rows = []
    for file in files:
        name, params = load_params(file)  # errors name the file
        entry = get(name)
        default = entry.make_params()
        overrides = {
            f.name: getattr(params, f.name)
            for f in fields(params)
            if getattr(params, f.name) != getattr(default, f.name)
        }
        label = f"{name} tuned ({Path(file).as_posix()})"  # as typed: two runs' files differ
        by_detection = entry.tracker_class().id_mapping != "same"
        rows.append(
            Row(label, name, overrides, detections=DetectionParams() if by_detection else None)
        )
    return tuple(rows)


def run(args: argparse.Namespace) -> int:
    from crowdsim.lab.experiments import COMPARE_ROWS, with_cmc

    rows = COMPARE_ROWS
    if args.trackers:
        from crowdsim.lab.experiments import Row
        from synth_data.detections import DetectionParams
        from tracker.registry import get

        known = {r.tracker for r in COMPARE_ROWS}
        extra = []
        for name in args.trackers:
            if name in known:
                continue
            entry = get(name)  # an unknown name lists the registry's trackers
            # a registered tracker without a row of its own (bqp-dense, one of yours): a row
            # under its name, fed simulated detections when it tracks by detection
            by_detection = entry.tracker_class().id_mapping != "same"
            extra.append(Row(name, name, detections=DetectionParams() if by_detection else None))
        rows = tuple(r for r in rows if r.tracker in args.trackers) + tuple(extra)
    if args.params:
        rows = tuple(rows) + tuned_rows(args.params)
    rows = with_cmc(rows) if args.cmc else rows
    return run_table_command(args, rows, f"compare on {table_source(args)}", "acc@15")
