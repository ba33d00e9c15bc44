#!/usr/bin/env python3
"""Regenerates models/quadruped.urdf from qz_drake/robot/quadruped.py (run after changing it)."""

from qz_drake.robot.quadruped import QUADRUPED_URDF, make_quadruped_urdf

if __name__ == "__main__":
    QUADRUPED_URDF.write_text(make_quadruped_urdf())
    print(f"wrote {QUADRUPED_URDF}")
