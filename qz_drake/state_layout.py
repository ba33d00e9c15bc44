"""Layout of the station's ``state`` vector, shared by every controller: the robot's
floating-base state, below every module that reads it.

Drake's floating-base convention: positions [quaternion w x y z of the base in world (4),
base position in world (3), 18 joint angles], velocities [base angular velocity in world (3),
base translational velocity in world (3), 18 joint rates]. Joints are leg-major: MF_j0, MF_j1,
MF_j2, RF_j0, ... (URDF coordinates, see qz_drake.robot.kinematics).
"""

import numpy as np
from pydrake.common.eigen_geometry import Quaternion
from pydrake.math import RigidTransform, RollPitchYaw, RotationMatrix

NUM_Q = 25
NUM_V = 24
STATE_SIZE = NUM_Q + NUM_V
BASE_QUAT = slice(0, 4)
BASE_POS = slice(4, 7)
# The base position's horizontal part and its height, by themselves.
BASE_XY = slice(4, 6)
BASE_Z = 6
JOINT_Q = slice(7, 25)
BASE_ANGVEL = slice(25, 28)
BASE_VEL = slice(28, 31)
JOINT_V = slice(31, 49)
IMU_SIZE = 10  # quaternion (4), angular velocity in base frame (3), proper acceleration in base frame (3)


def base_pose(x: np.ndarray) -> RigidTransform:
    """X_WB from a station state vector."""
    q = np.asarray(x[BASE_QUAT], dtype=float)
    quat = Quaternion(q / np.linalg.norm(q))
    return RigidTransform(quat, np.asarray(x[BASE_POS], dtype=float))


def base_rpy(x: np.ndarray) -> np.ndarray:
    return RollPitchYaw(RotationMatrix(base_pose(x).rotation())).vector()


def tilt_deg(x: np.ndarray) -> float:
    """Angle between the base's z axis and the world's z axis. [deg]"""
    R = base_pose(x).rotation().matrix()
    return float(np.degrees(np.arccos(np.clip(R[2, 2], -1.0, 1.0))))


def make_state(p_WB, rpy_WB, q_joints, v_base=None, v_joints=None) -> np.ndarray:
    """Builds a station state vector from a base pose (position, roll-pitch-yaw) and joints."""
    x = np.zeros(STATE_SIZE)
    x[BASE_QUAT] = RollPitchYaw(rpy_WB).ToQuaternion().wxyz()
    x[BASE_POS] = p_WB
    x[JOINT_Q] = q_joints
    if v_base is not None:
        x[BASE_ANGVEL.start:BASE_VEL.stop] = v_base
    if v_joints is not None:
        x[JOINT_V] = v_joints
    return x
