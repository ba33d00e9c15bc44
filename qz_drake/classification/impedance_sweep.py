"""The leg impedance stiffness sweep of paper 002, section 4.3 and Fig. 13.

One supporting leg of Qingzhui as a Drake MultibodyPlant: a hip body carrying its share of
the trunk (a tripod carries 60 kg, so 20 kg per leg) on a vertical prismatic joint, and the
lower leg (thigh, shank and foot, 1.16 kg) on a prismatic joint along the leg length l below
it. The ground under the foot is a unilateral spring-damper, 70 kN/m and 200 N*s/m (the
paper's model, after Bosworth et al.). The hip target height is a sine; the leg impedance is
the l row of Eq. 18 with M_d = 0,

    f_l = K (l_d - l) + B (l_d_dot - l_dot),     B = 200 N*s/m,

with no weight feedforward, so the leg sags M g / K under its load: about 4 cm at 5 kN/m and
1.3 cm at 15 kN/m, the paper's 0.04 m and 0.01 m.

What makes a stiff leg oscillate is the drive: the controller samples the leg at 1 kHz and
the torque loop of Eq. 20 follows its command with a finite bandwidth, modelled as a first-order
lag of ``torque_lag`` seconds. A spring force that arrives late removes damping (about
K * lag for the slow mode), so past K = B / lag the leg's damping turns negative: it rings
with a growing amplitude until the foot hops on the ground. The default lag, 12 ms (a 13 Hz
torque loop, plausible for a large geared drive with filtered torque sensing), puts that
boundary at 17 kN/m, between the paper's 15 and 25 kN/m; with an ideal drive (lag 0) no
stiffness rings. The robot starts in static balance, so the ringing grows from the sine
alone and takes a few seconds to show: the run lasts 5 s.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
from pydrake.multibody.plant import MultibodyPlant
from pydrake.multibody.tree import PrismaticJoint, SpatialInertia, UnitInertia
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import BasicVector, DiagramBuilder, LeafSystem
from pydrake.systems.primitives import FirstOrderLowPassFilter, LogVectorOutput

from qz_drake.errors import bad_value

GRAVITY = 9.81


@dataclasses.dataclass
class ImpedanceSweepConfig:
    # Leg stiffnesses along l to compare (paper: 5, 15 and 25 kN/m). [N/m]
    stiffnesses: list[float] = dataclasses.field(default_factory=lambda: [5e3, 15e3, 25e3])
    # Leg damping along l. [N*s/m]
    leg_damping: float = 200.0
    # Ground contact stiffness and damping (paper's simulated ground). [N/m], [N*s/m]
    ground_stiffness: float = 70e3
    ground_damping: float = 200.0
    # Mass the leg carries: a third of the 60 kg robot on a tripod. [kg]
    hip_mass: float = 20.0
    # Lower leg (thigh + shank + foot of qz_drake.robot.params). [kg]
    leg_mass: float = 1.16
    # Hip target: nominal height plus amplitude * sin(2 pi frequency t). [m], [m], [Hz]
    nominal_height: float = 0.55
    amplitude: float = 0.02
    frequency: float = 1.0
    # Controller sample period (1 kHz) and torque-loop lag (Eq. 20's PID bandwidth). [s]
    control_period: float = 0.001
    torque_lag: float = 0.012
    # Simulated time; the logged error is sampled at log_rate. [s], [Hz]
    duration: float = 5.0
    # Ringing is judged after this time, once the start's transient has decayed. [s]
    settle_time: float = 1.0
    log_rate: float = 1000.0


class LegImpedance1D(LeafSystem):
    """The l row of the spherical impedance (Eq. 18, M_d = 0), sampled every control period.

    .. pydrake_system::

        name: LegImpedance1D
        input_ports:
        - state
        output_ports:
        - force_command

    ``state`` is the plant's [z_hip, l, z_hip_dot, l_dot]; the command is the force along l
    (positive extends the leg), held between samples.
    """

    def __init__(self, *, stiffness: float, damping: float, target, control_period: float):
        super().__init__()
        self._k, self._b, self._target = stiffness, damping, target
        self._state = self.DeclareVectorInputPort("state", 4)
        self._command = self.DeclareDiscreteState(1)
        self.DeclarePeriodicDiscreteUpdateEvent(control_period, 0.0, self._update)
        self.DeclareStateOutputPort("force_command", self._command)

    def _update(self, context, discrete_state):
        z, l, _, l_dot = self._state.Eval(context)
        t = context.get_time()
        z_d, z_d_dot = self._target(t)
        # The foot stays on the ground (z_foot ~ 0), so the designed length follows the hip.
        force = self._k * (z_d - l) + self._b * (z_d_dot - l_dot)
        discrete_state.set_value(0, [force])


class GroundAndDrive(LeafSystem):
    """Generalized forces on [z_hip, l]: the unilateral ground spring-damper under the foot and
    the drive's force along l.

    .. pydrake_system::

        name: GroundAndDrive
        input_ports:
        - state
        - leg_force
        output_ports:
        - generalized_force
        - ground_force
    """

    def __init__(self, *, stiffness: float, damping: float):
        super().__init__()
        self._k, self._b = stiffness, damping
        self._state = self.DeclareVectorInputPort("state", 4)
        self._leg = self.DeclareVectorInputPort("leg_force", 1)
        self.DeclareVectorOutputPort("generalized_force", 2, self._calc_generalized)
        self.DeclareVectorOutputPort("ground_force", 1, self._calc_ground)

    def _ground(self, context) -> float:
        z, l, z_dot, l_dot = self._state.Eval(context)
        depth, depth_rate = l - z, l_dot - z_dot  # foot height is z - l
        return max(0.0, self._k * depth + self._b * depth_rate) if depth > 0.0 else 0.0

    def _calc_ground(self, context, output: BasicVector):
        output.SetFromVector([self._ground(context)])

    def _calc_generalized(self, context, output: BasicVector):
        ground = self._ground(context)
        leg = self._leg.Eval(context)[0]
        # d(z_foot)/dz = 1, d(z_foot)/dl = -1; the drive pushes hip and foot apart along l.
        output.SetFromVector([ground, -ground + leg])


def _check(config: ImpedanceSweepConfig) -> None:
    if not config.stiffnesses:
        raise bad_value("stiffnesses", config.stiffnesses, "give at least one stiffness")
    for k in config.stiffnesses:
        if not (math.isfinite(k) and k > 0):
            raise bad_value("stiffnesses", config.stiffnesses, "must be finite positive values in N/m")
    for name in ("leg_damping", "ground_stiffness", "hip_mass", "leg_mass", "nominal_height", "frequency",
                 "control_period", "duration", "log_rate"):
        value = getattr(config, name)
        if not (math.isfinite(value) and value > 0):
            raise bad_value(name, value, "must be finite and positive")
    for name in ("ground_damping", "amplitude", "torque_lag", "settle_time"):
        value = getattr(config, name)
        if not (math.isfinite(value) and value >= 0):
            raise bad_value(name, value, "must be finite and non-negative")


def simulate_leg(stiffness: float, config: ImpedanceSweepConfig | None = None) -> dict:
    """One run: returns times, hip target, hip height, error and ground force arrays."""
    config = config or ImpedanceSweepConfig()
    _check(dataclasses.replace(config, stiffnesses=[stiffness]))
    omega = 2.0 * math.pi * config.frequency

    def target(t):
        return (config.nominal_height + config.amplitude * math.sin(omega * t),
                config.amplitude * omega * math.cos(omega * t))

    builder = DiagramBuilder()
    plant = builder.AddSystem(MultibodyPlant(0.0))
    plant.set_name("one_leg")
    hip = plant.AddRigidBody("hip", SpatialInertia(config.hip_mass, np.zeros(3), UnitInertia.SolidSphere(0.1)))
    foot = plant.AddRigidBody("lower_leg", SpatialInertia(config.leg_mass, np.zeros(3),
                                                          UnitInertia.SolidSphere(0.05)))
    hip_joint = plant.AddJoint(PrismaticJoint("hip_z", plant.world_frame(), hip.body_frame(), [0.0, 0.0, 1.0]))
    leg_joint = plant.AddJoint(PrismaticJoint("leg_l", hip.body_frame(), foot.body_frame(), [0.0, 0.0, -1.0]))
    plant.Finalize()

    controller = builder.AddSystem(LegImpedance1D(stiffness=stiffness, damping=config.leg_damping,
                                                  target=target, control_period=config.control_period))
    forces = builder.AddSystem(GroundAndDrive(stiffness=config.ground_stiffness, damping=config.ground_damping))
    builder.Connect(plant.get_state_output_port(), controller.get_input_port())
    builder.Connect(plant.get_state_output_port(), forces.GetInputPort("state"))
    if config.torque_lag > 0:
        lag = builder.AddSystem(FirstOrderLowPassFilter(config.torque_lag, 1))
        builder.Connect(controller.get_output_port(), lag.get_input_port())
        builder.Connect(lag.get_output_port(), forces.GetInputPort("leg_force"))
    else:
        lag = None
        builder.Connect(controller.get_output_port(), forces.GetInputPort("leg_force"))
    builder.Connect(forces.GetOutputPort("generalized_force"), plant.get_applied_generalized_force_input_port())
    state_log = LogVectorOutput(plant.get_state_output_port(), builder, 1.0 / config.log_rate)
    ground_log = LogVectorOutput(forces.GetOutputPort("ground_force"), builder, 1.0 / config.log_rate)
    diagram = builder.Build()

    # Start in static balance on the target: ground and leg each carry their load.
    weight_total = (config.hip_mass + config.leg_mass) * GRAVITY
    weight_hip = config.hip_mass * GRAVITY
    depth = weight_total / config.ground_stiffness
    z0, _ = target(0.0)
    l0 = z0 - weight_hip / stiffness
    z_start = l0 - depth
    context = diagram.CreateDefaultContext()
    plant_context = plant.GetMyMutableContextFromRoot(context)
    _, z0_dot = target(0.0)
    hip_joint.set_translation(plant_context, z_start)
    leg_joint.set_translation(plant_context, l0)
    hip_joint.set_translation_rate(plant_context, z0_dot)
    leg_joint.set_translation_rate(plant_context, z0_dot)
    controller.GetMyMutableContextFromRoot(context).SetDiscreteState(0, [weight_hip])
    if lag is not None:
        lag.set_initial_output_value(lag.GetMyMutableContextFromRoot(context), [weight_hip])
    simulator = Simulator(diagram, context)
    simulator.get_mutable_integrator().set_maximum_step_size(2e-4)
    simulator.AdvanceTo(config.duration)
    log = state_log.FindLog(simulator.get_context())
    times = log.sample_times()
    hip_z = log.data()[0]
    desired = np.array([target(t)[0] for t in times])
    return {"times": times, "desired": desired, "hip": hip_z, "error": hip_z - desired,
            "ground_force": ground_log.FindLog(simulator.get_context()).data()[0]}


def oscillation_amplitude(times: np.ndarray, error: np.ndarray, frequency: float) -> float:
    """Half the peak-to-peak of what is left of the error once its mean and the part at the hip
    target's frequency (what a linear leg answers to the sine) are removed. [m]"""
    omega = 2.0 * math.pi * frequency
    basis = np.column_stack([np.ones_like(times), np.sin(omega * times), np.cos(omega * times)])
    coeffs, *_ = np.linalg.lstsq(basis, error, rcond=None)
    residual = error - basis @ coeffs
    return float(0.5 * (residual.max() - residual.min()))


# Residual oscillation, beyond the answer to the sine, that counts as ringing. [m]
OSCILLATION_THRESHOLD = 0.005


def run_sweep(config: ImpedanceSweepConfig | None = None) -> dict:
    """Fig. 13: the three stiffnesses; the result carries the config that produced it."""
    config = config or ImpedanceSweepConfig()
    _check(config)
    runs = [simulate_leg(k, config) for k in config.stiffnesses]
    amplitudes = []
    for r in runs:
        late = r["times"] >= min(config.settle_time, r["times"][-1] / 2)
        amplitudes.append(oscillation_amplitude(r["times"][late], r["error"][late], config.frequency))
    return {
        "stiffness_N_per_m": [float(k) for k in config.stiffnesses],
        "max_error_m": [float(np.max(np.abs(r["error"]))) for r in runs],
        "oscillates": [bool(a > OSCILLATION_THRESHOLD) for a in amplitudes],
        "oscillation_amplitude_m": amplitudes,
        "lost_ground_contact": [bool(np.any(r["ground_force"] <= 0.0)) for r in runs],
        "config": dataclasses.asdict(config),
        "runs": runs,
    }


def plot_sweep(result: dict, path) -> str:
    """The three error curves (hip height and target above, error below), as Fig. 13."""
    from qz_drake.classification.plots import plot_impedance_sweep

    return str(plot_impedance_sweep(result, path))
