#!/usr/bin/env python3
"""Regenerates models/qingzhui.urdf from qz_drake/robot/params.py (run after changing params)."""

from qz_drake.robot.model import QINGZHUI_URDF
from qz_drake.robot.urdf import make_urdf

if __name__ == "__main__":
    QINGZHUI_URDF.write_text(make_urdf())
    print(f"wrote {QINGZHUI_URDF}")
