"""qz_drake.classification."""
