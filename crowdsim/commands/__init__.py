"""Sub-commands of the ``crowdsim`` console command (one module each, see :mod:`crowdsim.cli`)."""
