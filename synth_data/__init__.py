"""synth_data package."""
