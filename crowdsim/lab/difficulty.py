"""Which difficulty costs which tracker: ``crowdsim difficulty``.

The calibration (:mod:`crowdsim.lab.calibration`) moves all appearance and camera knobs of a
sequence together until the anchor's tracker scores the paper's figure. It says nothing about which
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
from typing import Any

from crowdsim.knobs import apply_knobs, difficulty_groups

DIFFICULTY_GROUPS: dict[str, tuple[str, ...]] = difficulty_groups()
"""Knob groups (spec field names) of the calibration's difficulty scale, read from the ``group``
column of :data:`crowdsim.knobs.KNOBS`: look-alike heads, packed bodies, appearance change
(gait, arm swing, head turns), clutter and moving shadows, sensor noise with JPEG / H.264
compression, defocus and motion blur, illumination flicker, camera shake."""

DEFAULT_TRACKERS: tuple[str, ...] = ("ncc", "pnmc", "bqp")


def _slug(group: str) -> str:
    return re.sub(r"[^a-z0-9]+", "-", group.lower()).strip("-")


def variant_specs(spec: Any, groups: Sequence[str] | None = None) -> list[tuple[str, Any]]:
    """``[(variant, spec)]``: ``calibrated``, ``-<group>`` for every group (or only ``groups``,
    in table order), ``uncalibrated``.

    A variant's spec is named ``<sequence>.<variant>``; only its appearance and camera knobs
    differ (same seed, same crowd, same motion). A ``-<group>`` variant also draws the
    calibrated spec's ground (``camera.ground_margin_px``): without the shake the renderer
    would draw a smaller canvas, and with it other ground texture and clutter, so ``-shake``
    would measure another scene as well as the shake. The ``uncalibrated`` variant is the
    base spec as it renders on its own. Raises ``ValueError`` for a spec that was never
    calibrated (no ``base_*`` values recorded in ``[calibration]``) and for an unknown group.
    """
    chosen = check_groups(groups)
    from crowdsim.lab.calibration import uncalibrated_values

    base = uncalibrated_values(spec)
    if not base:
        raise ValueError(
            f"{spec.name}: not calibrated (no base_* values in [calibration]); "
            "run crowdsim calibrate first"
        )
    section = {name: sec for sec, name in base}
    out = [("calibrated", replace(spec, name=f"{spec.name}.calibrated"))]
    margin = ground_margin(spec)
    for group in chosen:
        # a knob with no base_* value recorded (added after the spec was calibrated) was not
        # moved by the calibration: the spec's own value is its base
        names = [n for n in DIFFICULTY_GROUPS[group] if n in section]
        values = {(section[n], n): base[(section[n], n)] for n in names}
        v = apply_knobs(spec, values)
        if ground_margin(v) < margin:  # the same ground as the calibrated spec
            v = replace(v, camera={**v.camera, "ground_margin_px": margin})
        out.append((f"-{group}", replace(v, name=f"{spec.name}.no-{_slug(group)}")))
    out.append(("uncalibrated", replace(apply_knobs(spec, base), name=f"{spec.name}.base")))
    return out


def ground_margin(spec: Any) -> int:
    """Ground, px, that ``spec``'s camera draws beyond each side of its frames
    (:attr:`crowdsim.camera.Camera.ground_margin`: its shake and shake bursts, or its
    ``ground_margin_px``)."""
    from crowdsim.camera import Camera, motion_values
    from crowdsim.events import of_kind

    camera = Camera(  # placeholders for the geometry, which the margin does not depend on
        px_per_m=1.0,
        width=8,
        height=8,
        **motion_values(spec.camera),
        shake_events=of_kind(spec.events, ("shake",)),
        ground_margin_px=spec.camera.get("ground_margin_px", 0),
    )
    return camera.ground_margin


def check_groups(groups: Sequence[str] | None) -> tuple[str, ...]:
    """The groups to attribute, in :data:`DIFFICULTY_GROUPS` order (all when ``None``);
    ``ValueError`` naming an unknown or repeated group."""
    if groups is None:
        return tuple(DIFFICULTY_GROUPS)
    if isinstance(groups, str):
        groups = (groups,)
    for g in groups:
        if g not in DIFFICULTY_GROUPS:
            raise ValueError(
                f"--groups: unknown group {g!r} (choose from {', '.join(DIFFICULTY_GROUPS)})"
            )
    if not groups or len(set(groups)) != len(groups):
        raise ValueError(f"--groups: name each group once, got {' '.join(groups) or 'none'}")
    return tuple(g for g in DIFFICULTY_GROUPS if g in groups)


def attribute(
    suite: str | os.PathLike[str],
    out: str | os.PathLike[str],
    *,
    only: Sequence[str] | None = None,
    trackers: Sequence[str] = DEFAULT_TRACKERS,
    groups: Sequence[str] | None = None,
    cmc: bool = False,
    frames: int | None = None,
    workers: int = 1,
    backend: str = "local",
    address: str | None = None,
    progress: bool = True,
    log: Callable[[str], None] = print,
) -> dict[str, Any]:
    """Track every difficulty variant of the suite's calibrated sequences with ``trackers``.

    ``suite`` is a built-in name or a suite folder (e.g. one written by ``crowdsim calibrate
    --out``). ``groups`` limits the variants to those groups (default: all). With ``cmc``,
    each tracker also runs with camera-motion compensation (``cmc=True``, row ``<name>+cmc``)
    on every variant, and the attribution adds what compensation regains on the calibrated
    spec (``cmc``) and, where shake costs the tracker points, the share of them it regains
    (``cmc_share_of_shake``).

    Writes the full table of :func:`crowdsim.lab.experiments.run_table` (``OUT/table.md``,
    ``table.csv``, ``cells.json``, curves) and ``OUT/attribution.md`` / ``.json``: per
    sequence and tracker, acc@15 calibrated, the points regained by removing each group, and
    acc@15 uncalibrated; ``frames`` is recorded and a cut run's title says so. Returns the
    attribution document. A tracker fed detections simulated from the ground truth (ByteTrack,
    OC-SORT) is refused: no knob reaches its input.
    """
    import json

    from crowdsim.lab.experiments import (
        Row,
        cell_key,
        cut_spec,
        key_frames,
        run_table,
        stale_note,
        takes_detections,
    )
    from synth_data.suites import suite_specs
    from tracker.registry import get

    if isinstance(trackers, str):
        trackers = (trackers,)  # one name, not its letters
    chosen = check_groups(groups)
    rows = []
    for name in trackers:
        entry = get(name)  # an unknown name fails before any work
        if cmc and "cmc" not in entry.field_names():
            raise ValueError(f"--cmc: tracker {name!r} has no camera-motion compensation")
        if takes_detections(name):
            # its detections are simulated from the ground truth: no knob reaches them, so
            # every group would read as costing it nothing
            raise ValueError(
                f"--trackers: {name!r} tracks detections simulated from the ground truth, "
                "which no appearance or camera knob changes; difficulty attributes to trackers "
                "that read the frames"
            )
        rows.append(Row(name, name))
        if cmc:
            rows.append(Row(f"{name}+cmc", name, {"cmc": True}))
    if not rows:
        raise ValueError("--trackers: name at least one tracker")
    if len(set(trackers)) != len(trackers):
        raise ValueError(f"--trackers: {', '.join(trackers)} names a tracker twice")
    from crowdsim.lab.calibration import uncalibrated_values

    listed = suite_specs(suite, list(only) if only else None)
    # every calibrated sequence (base_* values recorded); a sequence named in --only is
    # attributed or refused by name (variant_specs), also one with no [calibration] at all;
    # one never calibrated (a spec that only records the papers' figures, such as
    # calibrate --only copies) is left out of the whole suite
    specs = list(listed) if only else []
    if not only:
        specs = [s for s in listed if uncalibrated_values(s)]
        skipped = [s.name for s in listed if s.calibration and not uncalibrated_values(s)]
        if specs and skipped:
            log(f"not calibrated, left out: {', '.join(skipped)}")
    if not specs:
        raise ValueError(f"suite {str(suite)!r}: no calibrated sequence to attribute")
    variants = {s.name: variant_specs(s, chosen) for s in specs}
    all_specs = [v for vs in variants.values() for _, v in vs]
    doc: dict[str, Any] = {
        "suite": str(suite),
        "frames": frames,
        "groups": {g: DIFFICULTY_GROUPS[g] for g in chosen},
        "sequences": {},
    }

    def attribution(cells: dict[str, dict[str, Any]]) -> dict[str, Any]:
        """The attribution files' writers, from the finished cells (checked: figures as the
        trackers measured them)."""
        used: list[dict[str, Any]] = []
        for seq, vs in variants.items():
            per = {}
            for row in rows:
                keys = {
                    label: cell_key(cut_spec(sp, frames), row, key_frames(frames, sp))
                    for label, sp in vs
                }
                acc = {label: float(cells[key]["acc@15"]) for label, key in keys.items()}
                used += [cells[key] for key in keys.values()]
                per[row.label] = {
                    "calibrated": acc["calibrated"],
                    "uncalibrated": acc["uncalibrated"],
                    "regained": {g: acc[f"-{g}"] - acc["calibrated"] for g in chosen},
                }
            if cmc:
                for name in trackers:
                    r, c = per[name], per[f"{name}+cmc"]
                    r["cmc"] = c["calibrated"] - r["calibrated"]
                    shake = r["regained"].get("shake")
                    if shake is not None and shake > 0:
                        r["cmc_share_of_shake"] = r["cmc"] / shake
            doc["sequences"][seq] = per
        note = stale_note(used)
        if note is not None:  # some cells resumed from a run of other code
            doc["note"] = note
        return {
            "attribution.json": lambda p: p.write_text(json.dumps(doc, indent=2) + "\n"),
            "attribution.md": lambda p: p.write_text(attribution_table(doc)),
        }

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
        more_outputs=("attribution.json", "attribution.md"),
        finish=attribution,
        mean=False,  # its columns are variants of one sequence: their mean means nothing
    )
    return doc


def attribution_table(doc: dict[str, Any]) -> str:
    """Markdown: per sequence and tracker, acc@15 calibrated, the points each group costs
    (acc@15 with the group removed minus calibrated) and acc@15 uncalibrated; with ``cmc``
    rows, the points compensation regains on the calibrated spec and its share of shake's."""
    groups = list(doc["groups"])
    with_cmc = any("cmc" in r for per in doc["sequences"].values() for r in per.values())
    extra = ["+cmc", "cmc / shake"] if with_cmc else []
    head = ["sequence", "tracker", "calibrated", *[f"-{g}" for g in groups], "uncalibrated"]
    head += extra
    # a cut run says so, as its table.md does (the figures are not the whole sequences')
    cut = f", first {doc['frames']} frames of each sequence" if doc.get("frames") else ""
    lines = [
        f"# Difficulty attribution on {doc['suite']}{cut} (acc@15 %, and points regained)",
        "",
        "| " + " | ".join(head) + " |",
        "|" + "---|" * len(head),
    ]
    for seq, per in doc["sequences"].items():
        for trk, r in per.items():
            cells = [
                f"{r['calibrated']:.1f}",
                *[f"{r['regained'][g]:+.1f}" for g in groups],
                f"{r['uncalibrated']:.1f}",
            ]
            if with_cmc:
                share = r.get("cmc_share_of_shake")
                cells += [
                    f"{r['cmc']:+.1f}" if "cmc" in r else "",
                    f"{share:.0%}" if share is not None else "",
                ]
            lines.append(f"| {seq} | {trk} | " + " | ".join(cells) + " |")
    if doc.get("note"):
        lines += ["", doc["note"]]
    return "\n".join(lines) + "\n"
