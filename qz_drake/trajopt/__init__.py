"""qz_drake.trajopt."""
