"""Baseline trackers: independent NCC templates (:mod:`tracker.baselines.ncc`), mean-shift
(:mod:`tracker.baselines.meanshift`) and tracking-by-detection with ByteTrack / OC-SORT
(:mod:`tracker.baselines.detection`)."""
