"""Tracking: 4D-DPM losses, per-frame optimiser, temporal smoothing, multi-seed init, ADD evaluation (issue 5)."""
