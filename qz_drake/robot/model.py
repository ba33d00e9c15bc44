"""Qingzhui in a Drake MultibodyPlant: loading, joint ordering, standing state, SRBD inertia."""

from __future__ import annotations

import functools
from pathlib import Path

import numpy as np
from pydrake.multibody.parsing import Parser
from pydrake.multibody.plant import MultibodyPlant
from pydrake.multibody.tree import ModelInstanceIndex

from qz_drake.robot.params import DEFAULT_PARAMS, LEG_NAMES, QingzhuiParams
from qz_drake.robot.urdf import joint_names, make_urdf

MODELS_DIR = Path(__file__).resolve().parents[2] / "models"
QINGZHUI_URDF = MODELS_DIR / "qingzhui.urdf"


def add_qingzhui(plant: MultibodyPlant, params: QingzhuiParams = DEFAULT_PARAMS,
                 name: str = "qingzhui") -> ModelInstanceIndex:
    """Adds Qingzhui (floating base) to an unfinalized plant and returns its model instance.

    The URDF text is generated from ``params`` (so a payload or other change needs no file);
    with the default parameters it equals ``models/qingzhui.urdf``.
    """
    parser = Parser(plant)
    parser.SetAutoRenaming(True)
    (instance,) = parser.AddModelsFromString(make_urdf(params), "urdf")
    if name != "qingzhui":
        plant.RenameModelInstance(instance, name)
    return instance


class JointOrder:
    """Maps between the plant's generalized coordinates and the leg-major joint order.

    The station and every controller speak in the documented order (MF_j0, MF_j1, MF_j2, RF_j0,
    ...); the plant may number its joints differently (it orders them by tree level).
    """

    def __init__(self, plant: MultibodyPlant, instance: ModelInstanceIndex):
        names = joint_names()
        self.q_index = np.array([plant.GetJointByName(n, instance).position_start() for n in names])
        self.v_index = np.array([plant.GetJointByName(n, instance).velocity_start() for n in names])
        actuators = [plant.GetJointActuatorByName(f"{n}_motor", instance) for n in names]
        # Index of each actuator in the plant's actuation vector.
        self.u_index = np.array([a.input_start() for a in actuators])
        base = plant.GetBodyByName("base", instance)
        self.base_q_start = base.floating_positions_start()
        self.base_v_start = base.floating_velocities_start_in_v()

    def joint_q(self, q_plant: np.ndarray) -> np.ndarray:
        return np.asarray(q_plant)[..., self.q_index]

    def joint_v(self, v_plant: np.ndarray) -> np.ndarray:
        return np.asarray(v_plant)[..., self.v_index]

    def actuation(self, tau_legmajor: np.ndarray, num_actuators: int) -> np.ndarray:
        u = np.zeros(num_actuators)
        u[self.u_index] = tau_legmajor
        return u

    def from_actuation(self, u: np.ndarray) -> np.ndarray:
        return np.asarray(u)[..., self.u_index]


@functools.lru_cache(maxsize=16)
def standing_rigid_body(topology_name: str = "nominal",
                        params: QingzhuiParams = DEFAULT_PARAMS) -> tuple[float, np.ndarray, np.ndarray]:
    """Single-rigid-body properties of the whole robot standing in a topology's pose.

    Returns (mass [kg], rotational inertia about the CoM in the base frame (3, 3) [kg*m^2],
    CoM position in the base frame (3,) [m]) — the I of paper 000 Eq. 2.
    """
    from qz_drake.robot.topology import get_topology

    plant = MultibodyPlant(0.0)
    instance = add_qingzhui(plant, params)
    plant.Finalize()
    context = plant.CreateDefaultContext()
    order = JointOrder(plant, instance)
    q = plant.GetPositions(context)
    q[order.q_index] = get_topology(topology_name, params).standing_pose(params)
    plant.SetPositions(context, q)
    base = plant.GetBodyByName("base", instance)
    bodies = plant.GetBodyIndices(instance)
    M_BBo_B = plant.CalcSpatialInertia(context, base.body_frame(), bodies)
    mass = M_BBo_B.get_mass()
    p_BCm = M_BBo_B.get_com()
    I_BCm = M_BBo_B.Shift(p_BCm).CalcRotationalInertia().CopyToFullMatrix3()
    return float(mass), np.array(I_BCm), np.array(p_BCm)


__all__ = ["QINGZHUI_URDF", "add_qingzhui", "JointOrder", "standing_rigid_body", "LEG_NAMES"]
