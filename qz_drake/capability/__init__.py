"""qz_drake.capability."""
