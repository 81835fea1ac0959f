"""Synthetic dense-crowd benchmarks, and the one sequence face trackers read (SPEC §4).

* :mod:`synth_data.sequence`: :class:`SequenceSource`, the face of every sequence (name, frame
  rate, size, length, template size, frames, ground-truth points, births), with a video
  file (:class:`VideoSequence`), frames in memory (:class:`InMemorySequence`, e.g. built from
  a spec without touching disk, or :func:`synthetic_crowd`) and :func:`open_sequence`;
* :mod:`synth_data.scene`: spec -> simulated trajectories -> camera -> frames (no disk);
* :mod:`synth_data.spec`: sequence spec files (TOML/YAML) validated against a schema;
* :mod:`synth_data.suites`: the shipped suites ``ucf9``, ``galleria``, ``stress``;
* :mod:`synth_data.generate`: specs -> sequences on disk (resumable, atomic, local pool or
  Ray through :mod:`crowdsim.jobs`);
* :mod:`synth_data.writer`: render one trajectory set into a sequence folder (owned
  temporary folders, checksums);
* :mod:`synth_data.mot`: the MOTChallenge reader/writer (``read_sequence`` ->
  :class:`MotSequence`, a sequence source), which also reads real MOT17/MOT20 folders;
* :mod:`synth_data.detections`: simulated head detections drawn from ground truth;
* :mod:`synth_data.video`: video-codec compression of rendered frames.
"""

from synth_data.mot import MotSequence, read_sequence
from synth_data.sequence import (
    InMemorySequence,
    SequenceSource,
    VideoSequence,
    open_sequence,
    synthetic_crowd,
)

__all__ = [
    "InMemorySequence",
    "MotSequence",
    "SequenceSource",
    "VideoSequence",
    "open_sequence",
    "read_sequence",
    "synthetic_crowd",
]
