"""qz_drake.viz."""
