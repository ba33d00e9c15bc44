"""The six body topologies of Qingzhui (paper 000, section II-D and Fig. 3).

A topology is a knee bend direction per leg and a nominal foothold per leg. Fig. 2 of the paper
motivates both: knees bent inwards keep the shanks off a stair's edge, and front and hind feet
set further apart enlarge the support polygon. The figure itself is not machine-readable, so
the six are our reading of their names:

* ``nominal``: all knees out, footholds 0.20 m radially outside the hips;
* ``hind_bend`` / ``front_bend``: the three hind (RB, MB, LB) / front (MF, RF, LF) knees in;
* ``hind_1_bend`` / ``front_1_bend``: only the middle hind (MB) / front (MF) knee in;
* ``split_up``: knees out, front footholds 0.08 m further forward and hind ones 0.08 m
  further back.

Each topology also carries the half-size of the kinematic box of the trajectory optimiser
(paper 000 Eq. 1); a test checks that every corner of every box is reachable by the leg's
inverse kinematics in that topology's bend direction.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from qz_drake.errors import KinematicsError, bad_value
from qz_drake.robot import kinematics
from qz_drake.robot.params import DEFAULT_PARAMS, LEG_NAMES, NUM_LEGS, QingzhuiParams

TOPOLOGY_NAMES: tuple[str, ...] = (
    "nominal", "hind_bend", "front_bend", "hind_1_bend", "front_1_bend", "split_up")

FRONT_LEGS = (0, 1, 5)  # MF, RF, LF
HIND_LEGS = (2, 3, 4)  # RB, MB, LB

# Half-size of the kinematic box around each nominal foothold, body frame. [m]
DEFAULT_BOX_HALF_SIZE = (0.15, 0.12, 0.10)
# How far split_up moves front feet forward and hind feet back. [m]
SPLIT_UP_SHIFT = 0.08
SPLIT_UP_BOX_HALF_SIZE = (0.12, 0.12, 0.10)


@dataclasses.dataclass(frozen=True)
class Topology:
    """A body topology: knee bend per leg (+1 out, -1 in) and nominal footholds."""

    name: str
    # Knee bend per leg in LEG_NAMES order: +1 out, -1 in.
    bends: tuple[int, ...]
    # Nominal foot-sphere centres in the base frame at the standing height, (6, 3). [m]
    nominal_footholds: tuple[tuple[float, float, float], ...]
    # Half-size of the kinematic box around each nominal foothold. [m]
    box_half_size: tuple[float, float, float] = DEFAULT_BOX_HALF_SIZE

    @property
    def footholds_B(self) -> np.ndarray:
        return np.array(self.nominal_footholds, dtype=float)

    def standing_pose(self, params: QingzhuiParams = DEFAULT_PARAMS) -> np.ndarray:
        """The 18 URDF joint angles that put every foot on its nominal foothold."""
        q = np.zeros((NUM_LEGS, 3))
        for i in range(NUM_LEGS):
            q[i] = kinematics.solve_leg_inverse_kinematics(
                i, self.footholds_B[i], self.bends[i], params)
        return q.reshape(-1)


def _make(name: str, params: QingzhuiParams) -> Topology:
    bends = [kinematics.BEND_OUT] * NUM_LEGS
    footholds = np.array([params.nominal_foothold(i) for i in range(NUM_LEGS)])
    if name == "hind_bend":
        for i in HIND_LEGS:
            bends[i] = kinematics.BEND_IN
    elif name == "front_bend":
        for i in FRONT_LEGS:
            bends[i] = kinematics.BEND_IN
    elif name == "hind_1_bend":
        bends[LEG_NAMES.index("MB")] = kinematics.BEND_IN
    elif name == "front_1_bend":
        bends[LEG_NAMES.index("MF")] = kinematics.BEND_IN
    box = DEFAULT_BOX_HALF_SIZE
    if name == "split_up":
        footholds[list(FRONT_LEGS), 0] += SPLIT_UP_SHIFT
        footholds[list(HIND_LEGS), 0] -= SPLIT_UP_SHIFT
        # The spread feet are nearer the edge of the workspace: a shorter box along x.
        box = SPLIT_UP_BOX_HALF_SIZE
    return Topology(name=name, bends=tuple(bends), box_half_size=box,
                    nominal_footholds=tuple(tuple(float(v) for v in p) for p in footholds))


def get_topology(name: str, params: QingzhuiParams = DEFAULT_PARAMS) -> Topology:
    """Returns the named topology; raises KinematicsError naming ``topology`` if unknown."""
    if name not in TOPOLOGY_NAMES:
        raise bad_value("topology", name, f"expected one of {', '.join(TOPOLOGY_NAMES)}",
                        KinematicsError)
    return _make(name, params)


def all_topologies(params: QingzhuiParams = DEFAULT_PARAMS) -> list[Topology]:
    return [_make(name, params) for name in TOPOLOGY_NAMES]
