"""qz_drake.terrain."""
