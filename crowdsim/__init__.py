"""crowdsim: a social-force crowd simulator with exact ground truth for dense-crowd tracking."""

__version__ = "0.1.0"
