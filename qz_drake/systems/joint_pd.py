"""Joint PD with compensation of the legs' gravity and Coriolis torques (paper 000, Eq. 7).

    tau = Kp (q_des - q) + Kd (v_des - v) + tau_ext - J^T f_des

tau_ext cancels gravity and the Coriolis/centrifugal terms on the leg joints, computed by the
controller's own model of the robot (a MultibodyPlant without contact, as Drake's
InverseDynamicsController does): the controller sees only the station's ports. The last term
is an optional feedforward of desired foot forces f_des (world frame, e.g. the BLC's stance
forces), mapped to joint torques through each foot's Jacobian; with it the PD only corrects
errors instead of carrying the body's weight.
"""

from __future__ import annotations

import numpy as np
from pydrake.multibody.plant import MultibodyPlant
from pydrake.multibody.tree import JacobianWrtVariable
from pydrake.systems.framework import BasicVector, LeafSystem

from qz_drake.errors import bad_value
from qz_drake.robot.model import JointOrder, add_qingzhui
from qz_drake.robot.params import DEFAULT_PARAMS, LEG_NAMES, NUM_JOINTS, QingzhuiParams
from qz_drake.state_layout import JOINT_Q, JOINT_V, STATE_SIZE


class RobotControlModel:
    """The controller's model of Qingzhui: gravity, bias and foot Jacobians at a measured state."""

    def __init__(self, params: QingzhuiParams = DEFAULT_PARAMS):
        self.plant = MultibodyPlant(0.0)
        self.instance = add_qingzhui(self.plant, params)
        self.plant.Finalize()
        self.context = self.plant.CreateDefaultContext()
        self.order = JointOrder(self.plant, self.instance)
        self._feet = [self.plant.GetFrameByName(f"{leg}_foot", self.instance) for leg in LEG_NAMES]
        self._world = self.plant.world_frame()
        self._origin = np.zeros(3)
        if not (np.array_equal(self.order.q_index, np.arange(7, 25))
                and np.array_equal(self.order.v_index, np.arange(6, 24))):
            raise RuntimeError("unexpected joint ordering in the control plant")
        # Each leg's three velocity columns (contiguous, checked above): a slice, not a copy.
        self._leg_columns = [slice(6 + 3 * i, 9 + 3 * i) for i in range(len(LEG_NAMES))]

    def set_state(self, x: np.ndarray) -> None:
        self.plant.SetPositionsAndVelocities(self.context, x)

    def leg_compensation(self) -> np.ndarray:
        """Joint torques (18) cancelling gravity and Coriolis terms on the legs."""
        tau_g = self.plant.CalcGravityGeneralizedForces(self.context)
        bias = self.plant.CalcBiasTerm(self.context)
        return (bias - tau_g)[self.order.v_index]

    def foot_force_torques(self, f_W: np.ndarray) -> np.ndarray:
        """Joint torques (18) that make the feet push with -f_W, i.e. that balance ground
        reaction forces f_W (6, 3) acting on the feet: tau = -J^T f."""
        tau = np.zeros(NUM_JOINTS)
        for i in np.flatnonzero(f_W.any(axis=1)):  # runs at every plant step: no per-leg numpy
            J = self.plant.CalcJacobianTranslationalVelocity(
                self.context, JacobianWrtVariable.kV, self._feet[i], self._origin, self._world,
                self._world)
            tau[3 * i:3 * i + 3] = -J[:, self._leg_columns[i]].T @ f_W[i]
        return tau

    def foot_positions_W(self) -> np.ndarray:
        return np.array([self.plant.CalcPointsPositions(self.context, f, np.zeros(3), self._world)[:, 0]
                         for f in self._feet])


class JointPdController(LeafSystem):
    """Eq. 7 of paper 000 for all 18 joints.

    .. pydrake_system::

        name: JointPdController
        input_ports:
        - state
        - desired_state
        - foot_force_feedforward (optional)
        output_ports:
        - joint_torque

    ``desired_state`` holds q_des (18) then v_des (18), leg-major URDF coordinates;
    ``foot_force_feedforward`` (18) holds the desired ground reaction force on each foot in
    world coordinates, 3 per foot; left unconnected it is zero.

    Args:
        kp: joint stiffness Kp. [N*m/rad]
        kd: joint damping Kd. [N*m*s/rad]
        params: robot parameters of the controller's model.
        effort_limit: torques are clipped to +-effort_limit. [N*m]
        update_period: None: the torque is computed whenever it is read (Eq. 7's explicit PD
            must see every plant step). A period: computed at initialization and then every
            period, reading the inputs as they were before that time's other updates, and held
            in between: for the compensation and feedforward alone (kp = kd = 0) beside drives
            that run the PD themselves (the station's position mode), where a reference rate
            is enough and the plant may step without calling into Python. [s]
    """

    def __init__(self, *, kp: float, kd: float, params: QingzhuiParams = DEFAULT_PARAMS,
                 effort_limit: float | None = None, update_period: float | None = None):
        super().__init__()
        self._kp = np.broadcast_to(np.asarray(kp, dtype=float), (NUM_JOINTS,)).copy()
        self._kd = np.broadcast_to(np.asarray(kd, dtype=float), (NUM_JOINTS,)).copy()
        self._limit = params.effort_limit if effort_limit is None else effort_limit
        self._model = RobotControlModel(params)
        self._state = self.DeclareVectorInputPort("state", STATE_SIZE)
        self._desired = self.DeclareVectorInputPort("desired_state", 2 * NUM_JOINTS)
        self._feedforward = self.DeclareVectorInputPort("foot_force_feedforward", 3 * 6)
        if update_period is None:
            self.DeclareVectorOutputPort("joint_torque", NUM_JOINTS, self._calc_torque)
        else:
            if not (update_period > 0 and np.isfinite(update_period)):
                raise bad_value("update_period", update_period, "must be a positive period in seconds")
            held = self.DeclareDiscreteState(NUM_JOINTS)
            self.DeclarePeriodicDiscreteUpdateEvent(update_period, 0.0, self._update)
            self.DeclareInitializationDiscreteUpdateEvent(self._update)
            self.DeclareStateOutputPort("joint_torque", held)

    @property
    def model(self) -> RobotControlModel:
        return self._model

    def _update(self, context, discrete_state):
        self._calc_torque(context, discrete_state.get_mutable_vector(0))

    def _calc_torque(self, context, output: BasicVector):
        x = self._state.Eval(context)
        desired = self._desired.Eval(context)
        q, v = x[JOINT_Q], x[JOINT_V]
        tau = self._kp * (desired[:NUM_JOINTS] - q) + self._kd * (desired[NUM_JOINTS:] - v)
        self._model.set_state(x)
        tau += self._model.leg_compensation()
        if self._feedforward.HasValue(context):
            f = self._feedforward.Eval(context).reshape(6, 3)
            tau += self._model.foot_force_torques(f)
        # np.clip's values, without its Python wrapper (this runs at every plant step).
        output.SetFromVector(np.minimum(np.maximum(tau, -self._limit), self._limit))



def add_joint_pd(builder, station, references, *, params: QingzhuiParams, kp: float, kd: float,
                 position_mode: bool = False, update_period: float | None = None) -> JointPdController:
    """Adds Eq. 7's JointPdController between a system of references and a station; returns it.

    ``references`` has the InverseKinematicsTracker's outputs (``desired_state``,
    ``foot_force_feedforward``, and in position mode ``position_command`` and
    ``velocity_command``): the tracker itself, or the servo's ReferencePlayer. In position mode
    q_des and v_des go to the station's ``joint_position_command`` and
    ``joint_velocity_command`` (the drives' PD tracks them) and the controller adds only the
    compensation and force feedforward, every ``update_period`` (the references' period).
    """
    if position_mode:
        controller = builder.AddSystem(JointPdController(kp=0.0, kd=0.0, params=params, update_period=update_period))
        builder.Connect(references.GetOutputPort("position_command"), station.GetInputPort("joint_position_command"))
        builder.Connect(references.GetOutputPort("velocity_command"), station.GetInputPort("joint_velocity_command"))
    else:
        controller = builder.AddSystem(JointPdController(kp=kp, kd=kd, params=params))
    builder.Connect(station.GetOutputPort("state"), controller.GetInputPort("state"))
    builder.Connect(references.GetOutputPort("desired_state"), controller.GetInputPort("desired_state"))
    builder.Connect(references.GetOutputPort("foot_force_feedforward"), controller.GetInputPort("foot_force_feedforward"))
    builder.Connect(controller.GetOutputPort("joint_torque"), station.GetInputPort("joint_torque"))
    return controller
