"""The LCM messages: generated code is current, and the content checks name what is wrong."""

import filecmp
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from qz_drake.hardware.codec import command_problem, decode, joint_limits, status_problem
from qz_drake.hardware.qz_lcm import qz_command, qz_pose, qz_status
from qz_drake.robot.params import DEFAULT_PARAMS

HARDWARE = Path(__file__).resolve().parents[2] / "qz_drake" / "hardware"


def _lcm_gen() -> str:
    candidate = Path(sys.executable).with_name("lcm-gen")
    return str(candidate) if candidate.exists() else shutil.which("lcm-gen")


def test_generated_python_matches_the_message_definitions(tmp_path):
    """lcm-gen (from the lcm package) over messages/*.lcm reproduces qz_lcm/ byte for byte."""
    lcm_gen = _lcm_gen()
    assert lcm_gen, "lcm-gen not found (pip install lcm)"
    definitions = sorted((HARDWARE / "messages").glob("*.lcm"))
    assert [p.stem for p in definitions] == ["qz_command", "qz_planner", "qz_pose", "qz_reference", "qz_servo", "qz_status"]
    subprocess.run([lcm_gen, "--python", "--ppath", str(tmp_path), *map(str, definitions)], check=True)
    generated = sorted(p.name for p in (tmp_path / "qz_lcm").glob("*.py"))
    committed = sorted(p.name for p in (HARDWARE / "qz_lcm").glob("*.py"))
    assert generated == committed
    match, mismatch, errors = filecmp.cmpfiles(tmp_path / "qz_lcm", HARDWARE / "qz_lcm", generated, shallow=False)
    assert mismatch == [] and errors == [], f"regenerate with lcm-gen: {mismatch or errors}"


def good_status() -> qz_status:
    m = qz_status()
    m.utime, m.sequence, m.num_joints, m.num_feet = 500, 1, 18, 6
    m.joint_position = np.tile([0.0, 0.5, -1.0], 6).tolist()
    m.joint_velocity = [0.0] * 18
    m.joint_torque = [0.0] * 18
    m.orientation = [1.0, 0.0, 0.0, 0.0]
    m.angular_velocity = [0.0] * 3
    m.linear_acceleration = [0.0, 0.0, 9.81]
    m.foot_contact = [True] * 6
    return m


@pytest.mark.parametrize("field, index, value, words", [
    ("joint_position", 4, float("nan"), "joint_position[4] = nan"),
    ("joint_velocity", 0, float("inf"), "joint_velocity[0] = inf"),
    ("joint_position", 0, 1.5, "joint_position[0] = 1.500 rad outside"),
    ("orientation", 0, 2.0, "unit quaternion"),
    ("linear_acceleration", 2, float("-inf"), "linear_acceleration[2]"),
])
def test_a_malformed_status_is_named(field, index, value, words):
    lower, upper = joint_limits(DEFAULT_PARAMS)
    assert status_problem(good_status(), lower, upper, 0.05) == ""
    m = good_status()
    getattr(m, field)[index] = value
    assert words in status_problem(m, lower, upper, 0.05)


def test_wrong_sizes_and_wrong_types_are_rejected():
    lower, upper = joint_limits(DEFAULT_PARAMS)
    m = good_status()
    m.num_joints = 17
    m.joint_position, m.joint_velocity, m.joint_torque = ([0.0] * 17,) * 3
    assert "num_joints = 17" in status_problem(qz_status.decode(m.encode()), lower, upper, 0.05)
    # A pose on the status channel: the fingerprint differs.
    message, problem = decode(qz_status, qz_pose().encode())
    assert message is None and "not a qz_status" in problem
    assert decode(qz_status, b"") == (None, "")


def test_command_checks():
    c = qz_command()
    c.mode, c.num_joints = qz_command.MODE_TORQUE, 18
    c.joint_position, c.joint_velocity, c.joint_torque = [0.0] * 18, [0.0] * 18, [0.0] * 18
    assert command_problem(c, position_mode=False) == ""
    assert "mode = 0" in command_problem(c, position_mode=True)
    c.joint_velocity = [0.0] * 17
    assert "joint_velocity has 17 values" in command_problem(c, position_mode=False)
    c.joint_velocity = [0.0] * 18
    c.joint_velocity[5] = float("inf")
    assert "joint_velocity[5] = inf" in command_problem(c, position_mode=False)
    c.joint_velocity[5] = 0.0
    c.joint_torque[3] = float("nan")
    assert "joint_torque[3] = nan" in command_problem(c, position_mode=False)
    stop = qz_command()
    stop.mode = qz_command.MODE_SAFE_STOP
    assert command_problem(stop, position_mode=True) == ""
