"""Named benchmark suites: folders of spec files shipped inside the package (SPEC §4).

* ``ucf9``: ``seq1`` … ``seq9``, counterparts of the papers' nine sequences (frames, people,
  template px and scene type from SPEC §4). Each spec keeps its appearance and noise knobs and
  a ``[calibration]`` table with the paper's NCC score at 15 px, for the calibration step.
* ``galleria``: ``galleria1``, ``galleria2``: 2000-frame medium-density mall sequences.
* ``stress``: ``stress-1k``, ``stress-10k``, ``stress-50k`` agents.

Spec files live in ``synth_data/suites/<suite>/<sequence>.toml``.
"""

from __future__ import annotations

import re
from importlib import resources
from pathlib import Path

from synth_data.spec import SequenceSpec, load_spec

SUITE_NAMES: tuple[str, ...] = ("ucf9", "galleria", "stress")


def suite_dir(name: str) -> Path:
    """Folder holding the suite's spec files."""
    if name not in SUITE_NAMES:
        raise ValueError(f"--suite must be one of {', '.join(SUITE_NAMES)}, got {name!r}")
    return Path(str(resources.files("synth_data") / "suites" / name))


def _natural_key(path: Path) -> list[object]:
    return [int(p) if p.isdigit() else p for p in re.split(r"(\d+)", path.stem)]


def suite_specs(name: str, only: list[str] | None = None) -> list[SequenceSpec]:
    """The validated specs of suite ``name`` in natural order, optionally only some names."""
    folder = suite_dir(name)
    files = sorted(folder.glob("*.toml"), key=_natural_key)
    if not files:
        raise ValueError(f"suite {name!r} has no spec files in {folder}")
    specs = [load_spec(f) for f in files]
    if only:
        known = [s.name for s in specs]
        unknown = [o for o in only if o not in known]
        if unknown:
            raise ValueError(
                f"--only: no sequence {unknown[0]!r} in suite {name!r}; "
                f"choose from {', '.join(known)}"
            )
        specs = [s for s in specs if s.name in only]
    return specs
