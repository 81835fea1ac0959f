"""Synthetic dense-crowd benchmarks on disk (SPEC §4).

* :mod:`synth_data.spec`: sequence spec files (TOML/YAML) validated against a schema;
* :mod:`synth_data.suites`: the shipped suites ``ucf9``, ``galleria``, ``stress``;
* :mod:`synth_data.generate`: specs -> sequences (resumable, atomic, local pool or Ray);
* :mod:`synth_data.writer`: render one trajectory set into a sequence folder;
* :mod:`synth_data.mot`: the MOTChallenge reader/writer (``read_sequence``), which also reads
  real MOT17/MOT20 folders.
"""
