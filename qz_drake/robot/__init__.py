"""qz_drake.robot."""
