"""Dynamic alternating tripod trotting (paper 002, section 4.1, Fig. 10; section 2's middle level).

Each leg runs the gait state machine of Fig. 10:

* **LTS** (lifting): the scheduled end of the leg's support; the leg unloads and shortens,
  still in the "stance" impedance mode;
* **LDS** (landing): the swing, in the compliant "swing" mode, to the next foothold and on
  down until the station's ``foot_contact`` port reports the landing;
* **WAS** (weight acceptance): the leg takes its share of the weight over a short ramp;
* **THS** (thrust): the leg supports and pushes the body along until its tripod's support
  time ends, and the leg goes to LTS again.

Tripod A (MF, RB, LB) and tripod B (MB, RF, LF) alternate every ``phase_duration``: the
support times follow a clock, the landings follow the feet. The leg trajectory generator moves
a supporting foot backward under the body at the commanded velocity and swings a free foot
to a Raibert-style foothold; the body pose stabiliser spreads the body weight plus roll, pitch
and velocity corrections over the supporting feet as reference forces (the "force reference"
of Fig. 12). Its outputs feed a SphericalImpedance, whose stance stiffness per leg comes
from elsewhere (a constant, or the TerrainClassifier).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
from pydrake.systems.framework import LeafSystem

from qz_drake.errors import bad_value
from qz_drake.robot import kinematics
from qz_drake.robot.params import DEFAULT_PARAMS, NUM_LEGS, TRIPOD_A, QingzhuiParams
from qz_drake.state_layout import BASE_ANGVEL, BASE_QUAT, BASE_VEL, JOINT_Q, STATE_SIZE

# Gait states of Fig. 10(b).
LDS, WAS, THS, LTS = 0, 1, 2, 3
GAIT_STATE_NAMES = ("LDS", "WAS", "THS", "LTS")
GRAVITY = 9.81


@dataclasses.dataclass
class TrotConfig:
    # One tripod's support time (= the other tripod's swing time); a gait cycle is twice it. [s]
    phase_duration: float = 0.3
    # Swing apex above the stance height (paper 002's experiments: 5 cm). [m]
    step_height: float = 0.05
    # Fraction of the swing spent in LTS (unloading and shortening). [-]
    lift_fraction: float = 0.15
    # Fraction of the swing at which the designed trajectory touches down; the foot then keeps
    # reaching down (at most reach_depth below the stance height) until contact. [-]
    touchdown_fraction: float = 0.9
    # How far below its stance height a swinging foot reaches for a late ground. [m]
    reach_depth: float = 0.04
    # LDS ends on contact only after this fraction of the swing (scuffs at lift-off are not landings). [-]
    min_landing_fraction: float = 0.5
    # Duration of weight acceptance (WAS). [s]
    weight_acceptance_time: float = 0.05
    # Largest change of the commanded velocity (paper: 0 to 0.6 m/s in three cycles). [m/s^2]
    max_acceleration: float = 0.4
    # Foothold correction from the velocity error (Raibert). [s]
    foothold_gain: float = 0.05
    # Time of standing before the first step (settling onto the ground). [s]
    start_time: float = 0.3
    # Body pose stabiliser: roll / pitch stiffness and damping [N*m/rad], [N*m*s/rad]; body
    # velocity feedback [1/s] (a horizontal force of mass * gain * velocity error).
    attitude_stiffness: float = 3000.0
    attitude_damping: float = 300.0
    velocity_gain: float = 2.0
    # Controller update period (the station's plant step). [s]
    control_period: float = 0.002

    def check(self) -> "TrotConfig":
        for name in ("phase_duration", "step_height", "weight_acceptance_time", "max_acceleration",
                     "control_period", "reach_depth"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise bad_value(f"trot.{name}", value, "must be finite and positive")
        for name in ("lift_fraction", "touchdown_fraction", "min_landing_fraction"):
            value = getattr(self, name)
            if not (0.0 < value < 1.0):
                raise bad_value(f"trot.{name}", value, "must lie strictly between 0 and 1")
        if not self.lift_fraction < self.min_landing_fraction < self.touchdown_fraction:
            raise bad_value("trot.min_landing_fraction", self.min_landing_fraction,
                            "must lie between lift_fraction and touchdown_fraction")
        for name in ("foothold_gain", "start_time", "attitude_stiffness", "attitude_damping", "velocity_gain"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise bad_value(f"trot.{name}", value, "must be finite and non-negative")
        return self


def _smoothstep(s):
    """Position and derivative of 3 s^2 - 2 s^3, clamped to [0, 1]."""
    s = np.clip(s, 0.0, 1.0)
    return 3 * s * s - 2 * s ** 3, 6 * s * (1 - s)


class TrottingController(LeafSystem):
    """Gait state machine, leg trajectory generator and body pose stabiliser for the alternating
    tripod trot, updated every ``control_period``.

    .. pydrake_system::

        name: TrottingController
        input_ports:
        - state
        - foot_contact
        - velocity_command
        output_ports:
        - desired_foot_position
        - desired_foot_velocity
        - reference_force
        - mode
        - gait_state

    ``velocity_command`` is (forward, left, yaw rate) in the body frame [m/s, m/s, rad/s];
    the controller ramps to it at ``max_acceleration``. Desired foot positions, velocities and
    reference forces (the force each leg applies to its foot) are in the leg frames L, as the
    SphericalImpedance takes them; ``mode`` is 1 in WAS / THS / LTS ("stance") and 0 in LDS;
    ``gait_state`` holds each leg's state (LDS 0, WAS 1, THS 2, LTS 3).

    Args:
        config: gait parameters.
        params: robot parameters (the total mass, payload included, is the weight to carry).
        initial_feet_B: the standing feet in the base frame (6, 3); default the nominal footholds.
    """

    def __init__(self, *, config: TrotConfig | None = None, params: QingzhuiParams = DEFAULT_PARAMS,
                 initial_feet_B: np.ndarray | None = None):
        super().__init__()
        self._config = (config or TrotConfig()).check()
        self._params = params
        self._hips = np.array(params.hip_positions, dtype=float)
        self._R_BL = kinematics.all_leg_rotations(params)
        nominal = np.stack([params.nominal_foothold(i) for i in range(NUM_LEGS)])
        self._nominal = nominal if initial_feet_B is None else np.asarray(initial_feet_B, dtype=float).reshape(6, 3)
        self._group = np.array([0 if i in TRIPOD_A else 1 for i in range(NUM_LEGS)])
        self._state = self.DeclareVectorInputPort("state", STATE_SIZE)
        self._contact = self.DeclareVectorInputPort("foot_contact", NUM_LEGS)
        self._command = self.DeclareVectorInputPort("velocity_command", 3)
        # Discrete state: [gait state (6), entry time (6), velocity (3)], feet at lift-off (18),
        # feet targets in stance (18), footholds (18), and the outputs below.
        self._legs = self.DeclareDiscreteState(np.concatenate([np.full(6, THS), np.zeros(6), np.zeros(3)]))
        self._lift = self.DeclareDiscreteState(self._nominal.reshape(-1))
        self._stance_target = self._init_state(self._nominal.reshape(-1))
        self._foothold = self._init_state(self._nominal.reshape(-1))
        p_L0 = np.einsum("lji,lj->li", self._R_BL, self._nominal - self._hips)
        weight = params.total_mass * GRAVITY / NUM_LEGS
        self._p_out = self._init_state(p_L0.reshape(-1))
        self._v_out = self._init_state(np.zeros(18))
        self._f_out = self._init_state(np.tile([0.0, weight, 0.0], 6))
        self._mode_out = self._init_state(np.ones(6))
        self._gait_out = self._init_state(np.full(6, float(THS)))
        self.DeclarePeriodicDiscreteUpdateEvent(self._config.control_period, 0.0, self._update)
        self.DeclareStateOutputPort("desired_foot_position", self._p_out)
        self.DeclareStateOutputPort("desired_foot_velocity", self._v_out)
        self.DeclareStateOutputPort("reference_force", self._f_out)
        self.DeclareStateOutputPort("mode", self._mode_out)
        self.DeclareStateOutputPort("gait_state", self._gait_out)

    def _init_state(self, value):
        return self.DeclareDiscreteState(np.asarray(value, dtype=float))

    @property
    def config(self) -> TrotConfig:
        return self._config

    def _liftoff_time(self, t: float, group: int) -> float | None:
        """The start of the current support-end (lift-off) window of a tripod, or None before
        trotting starts. Tripod A lifts at start + k T, tripod B at start + T/2 + k T."""
        c = self._config
        t0 = c.start_time + group * c.phase_duration
        if t < t0:
            return None
        period = 2 * c.phase_duration
        return t0 + math.floor((t - t0) / period) * period

    def _swing_reference(self, s: float, lift: np.ndarray, land: np.ndarray, stance_z: float):
        """Foot position and velocity (per unit s) along the swing, s in [0, 1 + ...]."""
        c = self._config
        u, du = _smoothstep(s / c.touchdown_fraction)
        p = lift + (land - lift) * u
        dp = (land - lift) * du / c.touchdown_fraction
        # Height: up to the apex at mid-swing, down to the stance height at touchdown, then on
        # down slowly, reaching for a ground that is lower than expected.
        z0, z1 = lift[2], stance_z
        if s < c.touchdown_fraction:
            w = s / c.touchdown_fraction
            base = z0 + (z1 - z0) * u
            bump = c.step_height * 16 * w * w * (1 - w) * (1 - w)
            dbump = c.step_height * 16 * 2 * w * (1 - w) * (1 - 2 * w) / c.touchdown_fraction
            p[2] = base + bump
            dp[2] = (z1 - z0) * du / c.touchdown_fraction + dbump
        else:
            rate = c.reach_depth / (1.0 - c.touchdown_fraction)
            p[2] = max(z1 - rate * (s - c.touchdown_fraction), z1 - c.reach_depth)
            dp[2] = -rate if p[2] > z1 - c.reach_depth else 0.0
        return p, dp

    def _update(self, context, discrete_state):
        c = self._config
        t = context.get_time()
        dt = c.control_period
        x = self._state.Eval(context)
        contact = self._contact.Eval(context) > 0.5
        command = self._command.Eval(context)
        legs = discrete_state.get_mutable_vector(self._legs).get_mutable_value()
        lift = discrete_state.get_mutable_vector(self._lift).get_mutable_value().reshape(6, 3)
        target = discrete_state.get_mutable_vector(self._stance_target).get_mutable_value().reshape(6, 3)
        foothold = discrete_state.get_mutable_vector(self._foothold).get_mutable_value().reshape(6, 3)
        state, entered, velocity = legs[0:6], legs[6:12], legs[12:15]

        # Ramp the commanded velocity (the body's acceleration limit).
        step = np.clip(command - velocity, -c.max_acceleration * dt, c.max_acceleration * dt)
        velocity += step
        v_xy, yaw_rate = velocity[:2], velocity[2]

        quat = x[BASE_QUAT] / np.linalg.norm(x[BASE_QUAT])
        R_WB = _rotation(quat)
        v_B = R_WB.T @ x[BASE_VEL]
        feet_B = kinematics.all_foot_positions(x[JOINT_Q], self._params)
        stance_z = self._nominal[:, 2]

        p_des = np.empty((6, 3))
        v_des = np.zeros((6, 3))
        support = np.zeros(6)
        for i in range(NUM_LEGS):
            liftoff = self._liftoff_time(t, self._group[i])
            # Support ends by the clock: a leg still supporting after its tripod's lift-off
            # time goes to LTS.
            if state[i] in (WAS, THS) and liftoff is not None and entered[i] < liftoff <= t:
                state[i], entered[i] = LTS, liftoff
                lift[i] = feet_B[i]
                # Next foothold: the nominal one, ahead by half a stance of travel, plus the
                # velocity error correction.
                half = 0.5 * c.phase_duration
                ahead = np.array([v_xy[0], v_xy[1], 0.0]) * half
                turn = yaw_rate * half * np.array([-self._nominal[i, 1], self._nominal[i, 0], 0.0])
                correction = c.foothold_gain * np.array([v_B[0] - v_xy[0], v_B[1] - v_xy[1], 0.0])
                foothold[i] = self._nominal[i] + ahead + turn + correction
            if state[i] in (LTS, LDS):
                s = (t - entered[i]) / c.phase_duration
                if state[i] == LTS and s >= c.lift_fraction:
                    state[i] = LDS
                if state[i] == LDS and s >= c.min_landing_fraction and contact[i]:
                    state[i], entered[i] = WAS, t
                    target[i] = feet_B[i]
                    target[i, 2] = min(feet_B[i, 2], stance_z[i])
                else:
                    p, dp = self._swing_reference(s, lift[i], foothold[i], stance_z[i])
                    p_des[i], v_des[i] = p, dp / c.phase_duration
                    continue
            if state[i] == WAS and t - entered[i] >= c.weight_acceptance_time:
                state[i] = THS
            # Supporting: the foot target moves backward under the body at the commanded
            # velocity (and turns with the yaw rate); its height returns to the stance height.
            rel_v = -np.array([v_xy[0] - yaw_rate * target[i, 1], v_xy[1] + yaw_rate * target[i, 0], 0.0])
            target[i] += rel_v * dt
            target[i, 2] += (stance_z[i] - target[i, 2]) * min(1.0, dt / 0.1)
            p_des[i], v_des[i] = target[i], rel_v
            support[i] = 1.0 if state[i] == THS else min(1.0, (t - entered[i]) / c.weight_acceptance_time)
        # LTS legs unload over the lift fraction.
        for i in range(NUM_LEGS):
            if state[i] == LTS:
                s = (t - entered[i]) / c.phase_duration
                support[i] = max(0.0, 1.0 - s / c.lift_fraction) * 0.3

        forces_W = self._stabiliser(R_WB, x, feet_B, support, velocity)
        p_L = np.einsum("lji,lj->li", self._R_BL, p_des - self._hips)
        v_L = np.einsum("lji,lj->li", self._R_BL, v_des)
        # The leg pushes its foot against the ground: the opposite of the force on the body.
        f_L = np.einsum("lji,lj->li", self._R_BL, -(forces_W @ R_WB))
        discrete_state.get_mutable_vector(self._p_out).SetFromVector(p_L.reshape(-1))
        discrete_state.get_mutable_vector(self._v_out).SetFromVector(v_L.reshape(-1))
        discrete_state.get_mutable_vector(self._f_out).SetFromVector(f_L.reshape(-1))
        discrete_state.get_mutable_vector(self._mode_out).SetFromVector((state != LDS).astype(float))
        discrete_state.get_mutable_vector(self._gait_out).SetFromVector(state.copy())

    def _stabiliser(self, R_WB, x, feet_B, support, velocity) -> np.ndarray:
        """Forces (world frame, on the body, per foot) that carry the weight, level the body and
        hold the commanded velocity, spread over the supporting feet by weighted least squares."""
        c = self._config
        forces = np.zeros((6, 3))
        total = support.sum()
        if total < 1e-6:
            return forces
        mass = self._params.total_mass
        rpy = _roll_pitch(R_WB)
        w_W = x[BASE_ANGVEL]
        # Yaw-aligned frame: roll and pitch moments about the body's heading axes.
        yaw = math.atan2(R_WB[1, 0], R_WB[0, 0])
        cy, sy = math.cos(yaw), math.sin(yaw)
        R_yaw = np.array([[cy, -sy, 0.0], [sy, cy, 0.0], [0.0, 0.0, 1.0]])
        w_H = R_yaw.T @ w_W
        moment_H = np.array([-c.attitude_stiffness * rpy[0] - c.attitude_damping * w_H[0],
                             -c.attitude_stiffness * rpy[1] - c.attitude_damping * w_H[1]])
        feet_H = (feet_B @ R_WB.T) @ R_yaw  # feet relative to the base, heading frame
        weight = mass * GRAVITY
        # Vertical forces f: sum f = weight, sum y f = M_x, sum -x f = M_y.
        A = np.vstack([np.ones(6), feet_H[:, 1], -feet_H[:, 0]])
        b = np.array([weight, moment_H[0], moment_H[1]])
        W = np.diag(support)
        f_nominal = support * weight / total
        AWA = A @ W @ A.T + 1e-6 * np.eye(3)
        f_z = f_nominal + W @ A.T @ np.linalg.solve(AWA, b - A @ f_nominal)
        f_z = np.clip(f_z, 0.0, 3.0 * weight / max(total, 1.0)) * (support > 0)
        forces[:, 2] = f_z
        # Horizontal: velocity feedback, shared in proportion to the vertical load.
        v_H = R_yaw.T @ x[BASE_VEL]
        f_xy_H = mass * c.velocity_gain * (velocity[:2] - v_H[:2])
        f_xy_W = R_yaw[:2, :2] @ f_xy_H
        share = f_z / max(f_z.sum(), 1e-9)
        forces[:, :2] = np.outer(share, f_xy_W)
        return forces


def _rotation(quat_wxyz: np.ndarray) -> np.ndarray:
    w, x, y, z = quat_wxyz
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def _roll_pitch(R: np.ndarray) -> np.ndarray:
    """Roll and pitch (ZYX convention) of a rotation matrix."""
    return np.array([math.atan2(R[2, 1], R[2, 2]), math.asin(-max(-1.0, min(1.0, R[2, 0])))])


def add_trotting_controller(builder, station, info, *, config: TrotConfig | None = None,
                            stiffness_port=None, stance_stiffness=9000.0, velocity_port=None,
                            velocity: tuple[float, float, float] = (0.0, 0.0, 0.0)):
    """Wires TrottingController -> SphericalImpedance -> station; returns (trot, impedance).

    The stance stiffness comes from ``stiffness_port`` (e.g. a TerrainClassifier's output) or
    is the constant ``stance_stiffness`` [N/m] (one value, or one per leg); the velocity
    command from ``velocity_port`` or the constant ``velocity``.
    """
    from pydrake.systems.primitives import ConstantVectorSource

    from qz_drake.systems.impedance import SphericalImpedance

    feet_B = kinematics.all_foot_positions(info.initial_state[JOINT_Q], info.params)
    trot = builder.AddSystem(TrottingController(config=config, params=info.params, initial_feet_B=feet_B))
    trot.set_name("trotting_controller")
    impedance = builder.AddSystem(SphericalImpedance(params=info.params, **TROT_IMPEDANCE_GAINS))
    impedance.set_name("spherical_impedance")
    builder.Connect(station.GetOutputPort("state"), trot.GetInputPort("state"))
    builder.Connect(station.GetOutputPort("foot_contact"), trot.GetInputPort("foot_contact"))
    if velocity_port is None:
        velocity_port = builder.AddSystem(ConstantVectorSource(np.asarray(velocity, dtype=float))).get_output_port()
    builder.Connect(velocity_port, trot.GetInputPort("velocity_command"))
    for name in ("desired_foot_position", "desired_foot_velocity", "reference_force", "mode"):
        builder.Connect(trot.GetOutputPort(name), impedance.GetInputPort(name))
    if stiffness_port is None:
        stiffness = np.broadcast_to(np.asarray(stance_stiffness, dtype=float), (NUM_LEGS,)).copy()
        stiffness_port = builder.AddSystem(ConstantVectorSource(stiffness)).get_output_port()
    builder.Connect(stiffness_port, impedance.GetInputPort("stiffness"))
    builder.Connect(station.GetOutputPort("state"), impedance.GetInputPort("state"))
    builder.Connect(impedance.GetOutputPort("joint_torque"), station.GetInputPort("joint_torque"))
    return trot, impedance


# Impedance gains for trotting: a swing fast enough for 0.3 s phases (the leg's inertia about
# the hip with the reflected rotor inertia is about 0.2 kg*m^2), a stance angular stiffness
# that keeps the supporting foot under the body.
TROT_IMPEDANCE_GAINS = dict(swing_stiffness=(4000.0, 1500.0, 1500.0), swing_damping=(80.0, 35.0, 35.0),
                            stance_angular_stiffness=(1500.0, 1500.0), stance_damping=(200.0, 40.0, 40.0))
