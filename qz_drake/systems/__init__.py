"""qz_drake.systems."""
