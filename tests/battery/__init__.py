"""The bad-input battery: a harness and one case file per area."""
