"""Content checks of the LCM messages (sizes, finite values, joint limits, modes).

Each returns an empty string for a good message, else what is wrong with it, so that the
watchdog can count the message as rejected and say why in its latch reason.
"""

from __future__ import annotations

import struct

import math

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.lcm import SerializerInterface

from qz_drake.hardware.qz_lcm import qz_command, qz_pose, qz_status
from qz_drake.robot.params import NUM_JOINTS, NUM_LEGS, QingzhuiParams


class EncodedMessageSerializer(SerializerInterface):
    """The LCM systems' serializer that keeps a message as its encoded bytes.

    Drake deep-copies a subscriber's abstract state at every update; a decoded Python message
    costs ~50 us to copy, its bytes nothing. The receiving LeafSystem decodes the newest
    message once per control period (``decode``), and a message of the wrong type (fingerprint)
    is rejected there like any other malformed message.
    """

    def __init__(self, lcm_type):
        SerializerInterface.__init__(self)
        self._lcm_type = lcm_type

    def __repr__(self):
        return f"EncodedMessageSerializer({self._lcm_type.__name__})"

    def CreateDefaultValue(self):
        return AbstractValue.Make(b"")

    def Deserialize(self, buffer, abstract_value):
        abstract_value.set_value(bytes(buffer))

    def Serialize(self, abstract_value):
        return abstract_value.get_value()


def decode(lcm_type, data: bytes):
    """(message, problem): the decoded message, or None and why it could not be decoded;
    (None, "") for no message yet (empty bytes)."""
    if not data:
        return None, ""
    try:
        return lcm_type.decode(data), ""
    except Exception as e:  # a wrong fingerprint or a truncated buffer: the sender's fault
        return None, f"not a {lcm_type.__name__} ({e})"


def message_key(message, problem: str, data: bytes) -> tuple[int, int]:
    """What tells a new message from the one seen before: (utime, sequence); (0, 0) for none;
    for an undecodable one (-1, a hash of its bytes), so that it is counted once."""
    if message is not None:
        return int(message.utime), int(message.sequence)
    return (-1, hash(data)) if problem else (0, 0)


# qz_status, qz_pose and qz_command begin with the type's 8-byte fingerprint, then int64 utime and
# int64 sequence (big-endian): read from the bytes without decoding the rest.
_UTIME_SEQUENCE = struct.Struct(">qq")


def encoded_key(data: bytes) -> tuple[int, int]:
    """(utime, sequence) of an encoded qz_status, qz_pose or qz_command, read from its header (a
    callback that only needs when a message came or which it is, at 500 Hz, without decoding it)."""
    return _UTIME_SEQUENCE.unpack_from(data, 8)


def joint_limits(params: QingzhuiParams) -> tuple[np.ndarray, np.ndarray]:
    """Lower and upper limits (18,) of all joints, leg-major."""
    lower, upper = params.joint_limits()
    return np.tile(lower, NUM_LEGS), np.tile(upper, NUM_LEGS)


def _sized(values, n: int, name: str) -> str:
    return "" if len(values) == n else f"{name} has {len(values)} values, expected {n}"


def _finite(values, name: str) -> str:
    # A sum of floats is finite only if every term is (NaN and inf propagate); checked per
    # value only to name the bad one. (Plain Python: these lists are short, numpy is slower.)
    if math.isfinite(math.fsum(values)):
        return ""
    k = next(k for k, v in enumerate(values) if not math.isfinite(v))
    return f"{name}[{k}] = {values[k]}"


def status_problem(m: qz_status, lower: np.ndarray, upper: np.ndarray, margin: float) -> str:
    """What is wrong with a status: sizes, NaN or infinite values, angles outside the limits."""
    if m.num_joints != NUM_JOINTS or m.num_feet != NUM_LEGS:
        return f"num_joints = {m.num_joints}, num_feet = {m.num_feet}, expected {NUM_JOINTS}, {NUM_LEGS}"
    for name in ("joint_position", "joint_velocity", "joint_torque"):
        problem = _sized(getattr(m, name), NUM_JOINTS, name) or _finite(getattr(m, name), name)
        if problem:
            return problem
    problem = _sized(m.foot_contact, NUM_LEGS, "foot_contact")
    for name in ("orientation", "angular_velocity", "linear_acceleration"):
        problem = problem or _finite(getattr(m, name), name)
    if problem:
        return problem
    norm = math.sqrt(sum(v * v for v in m.orientation))
    if not 0.9 < norm < 1.1:
        return f"orientation has norm {norm:.3f}, expected a unit quaternion"
    q = np.asarray(m.joint_position)
    outside = (q < lower - margin) | (q > upper + margin)
    if outside.any():
        j = int(np.flatnonzero(outside)[0])
        return f"joint_position[{j}] = {q[j]:.3f} rad outside [{lower[j]:.2f}, {upper[j]:.2f}]"
    return ""


def command_problem(m: qz_command, position_mode: bool) -> str:
    """What is wrong with a command for a driver in torque or position mode."""
    if m.mode == qz_command.MODE_SAFE_STOP:
        return ""
    expected = qz_command.MODE_POSITION if position_mode else qz_command.MODE_TORQUE
    if m.mode != expected:
        return f"mode = {m.mode}, the robot runs in mode {expected}"
    if m.num_joints != NUM_JOINTS:
        return f"num_joints = {m.num_joints}, expected {NUM_JOINTS}"
    for name in ("joint_position", "joint_velocity", "joint_torque"):
        problem = _sized(getattr(m, name), NUM_JOINTS, name) or _finite(getattr(m, name), name)
        if problem:
            return problem
    return ""


def pose_problem(m: qz_pose) -> str:
    problem = ""
    for name in ("position", "orientation", "linear_velocity"):
        problem = problem or _finite(getattr(m, name), name)
    return problem
