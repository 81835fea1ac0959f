"""The upper library: experiments that run trackers over generated sequences.

* :mod:`crowdsim.lab.experiments` -- ``compare`` and ``ablation``: the papers' tables, resumable
  and parallel on :mod:`crowdsim.jobs`;
* :mod:`crowdsim.lab.calibration` -- ``calibrate``: a suite's difficulty searched until its
  anchor tracker scores the paper's column;
* :mod:`crowdsim.lab.difficulty` -- ``difficulty``: which knob group costs which tracker.

The lab imports the simulator, the renderer, :mod:`synth_data` and :mod:`tracker`; nothing below
it imports the lab, and the lab never imports the application (``crowdsim.cli``,
``crowdsim.commands``, ``crowdsim.bench``).
"""
