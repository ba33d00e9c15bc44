"""qz_drake.planning."""
