"""The LCM station as ``qz simulate --station lcm`` runs it.

LcmLoopbackStation: the interface and the simulated robot driver in one diagram over one LCM
instance (in-process ``memq://``): deterministic, no real-time pacing, the controller on one
side of the protocol and the simulated robot on the other, exactly as against
``qz robot-sim`` or the robot. What the tests run.

RemoteLcmStation: the interface alone, against a driver in another process (``qz robot-sim``
or the robot) at a network URL; the simulator must then be paced to real time.
"""

from __future__ import annotations

import numpy as np
from pydrake.lcm import DrakeLcm
from pydrake.systems.framework import Diagram, DiagramBuilder
from pydrake.systems.primitives import ConstantVectorSource

from qz_drake.config import Scenario
from qz_drake.hardware.config import HardwareConfig
from qz_drake.hardware.driver import QingzhuiRobotDriver
from qz_drake.hardware.interface import make_hardware_interface
from qz_drake.hardware.relay import connect_lcm

# The station's ports that controllers use: all of them come from the interface.
CONTROLLER_OUTPUTS = ("state", "joint_torque_measured", "imu", "foot_contact")
# Simulation-only outputs for monitors and metrics, from the driver side.
DRIVER_OUTPUTS = ("trunk_contact", "foot_normal_force", "contact_results", "body_poses", "true_state")


class LcmLoopbackStation(Diagram):
    """QingzhuiHardwareInterface wired over LCM to a QingzhuiRobotDriver.

    .. pydrake_system::

        name: LcmLoopbackStation
        input_ports:
        - joint_torque
        - joint_position_command (position mode)
        - joint_velocity_command (position mode)
        output_ports:
        - state
        - joint_torque_measured
        - imu
        - foot_contact
        - trunk_contact
        - foot_normal_force
        - contact_results
        - body_poses
        - true_state

    The first four outputs and the inputs are the interface's (what the controller sees); the
    rest are the driver's simulation truth (never for controllers).

    Args:
        scenario: the scenario.
        lcm: the LCM instance both sides share (``DrakeLcm("memq://")``: in-process).
        config: protocol settings.
        meshcat, mesh_dir: for the driver's station.
        status_filter, pose_filter, command_filter: hooks on the published messages (see StatusPublisher and
            CommandSender).
    """

    def __init__(self, *, scenario: Scenario, lcm: DrakeLcm, config: HardwareConfig | None = None,
                 meshcat=None, mesh_dir=None, status_filter=None, pose_filter=None, command_filter=None):
        super().__init__()
        builder = DiagramBuilder()
        self.driver = builder.AddSystem(QingzhuiRobotDriver(
            scenario=scenario, lcm=lcm, config=config, meshcat=meshcat, mesh_dir=mesh_dir,
            status_filter=status_filter, pose_filter=pose_filter))
        interface, _ = make_hardware_interface(scenario, lcm=lcm, config=config, command_filter=command_filter)
        self.interface = builder.AddSystem(interface)
        self.info = self.driver.info
        self.lcm = lcm
        builder.ExportInput(self.interface.GetInputPort("joint_torque"), "joint_torque")
        if scenario.station.control_mode == "position":
            builder.ExportInput(self.interface.GetInputPort("joint_position_command"), "joint_position_command")
            builder.ExportInput(self.interface.GetInputPort("joint_velocity_command"), "joint_velocity_command")
        for name in CONTROLLER_OUTPUTS:
            builder.ExportOutput(self.interface.GetOutputPort(name), name)
        for name in DRIVER_OUTPUTS:
            builder.ExportOutput(self.driver.GetOutputPort(name), name)
        builder.BuildInto(self)
        self.set_name("station")

    def station_metrics(self, root_context) -> dict:
        """Both ends' watchdog and clamp counters, and the first safe stop, for a run's metrics."""
        ends = {"interface": self.interface.counters(root_context), "driver": self.driver.counters(root_context)}
        return {"lcm_interface": ends["interface"], "lcm_driver": ends["driver"], "safe_stop": first_safe_stop(ends)}


def first_safe_stop(ends: dict[str, dict]) -> str:
    """The earliest latched safe stop among the link ends' counters ({"interface": ...}), as
    "at 0.420 s on the interface: <its reason>"; "" when none latched."""
    latched = [(c["safe_stop_time_s"], end, c["safe_stop_reason"]) for end, c in ends.items()
               if c["safe_stop_latched"]]
    if not latched:
        return ""
    t, end, reason = min(latched)
    return f"at {t:.3f} s on the {end}: {reason}"


def make_lcm_loopback_station(scenario: Scenario, meshcat=None, *, mesh_dir=None, lcm_url: str = "memq://",
                              config: HardwareConfig | None = None, **filters):
    """A make_station-compatible factory: (LcmLoopbackStation, StationInfo)."""
    station = LcmLoopbackStation(scenario=scenario, lcm=DrakeLcm(lcm_url), config=config, meshcat=meshcat,
                                 mesh_dir=mesh_dir, **filters)
    return station, station.info


class RemoteLcmStation(Diagram):
    """QingzhuiHardwareInterface against a driver elsewhere, with the outputs simulate() logs.

    .. pydrake_system::

        name: RemoteLcmStation
        input_ports:
        - joint_torque
        - joint_position_command (position mode)
        - joint_velocity_command (position mode)
        output_ports:
        - state
        - joint_torque_measured
        - imu
        - foot_contact
        - trunk_contact

    A robot does not report trunk contact: ``trunk_contact`` is NaN (never counted as a
    contact), and the metrics say ``trunk_contact_observed: false``.
    """

    def __init__(self, *, scenario: Scenario, lcm: DrakeLcm, config: HardwareConfig | None = None):
        super().__init__()
        builder = DiagramBuilder()
        self.interface, self.info = make_hardware_interface(scenario, lcm=lcm, config=config)
        builder.AddSystem(self.interface)
        unknown = builder.AddSystem(ConstantVectorSource(np.array([np.nan])))
        builder.ExportInput(self.interface.GetInputPort("joint_torque"), "joint_torque")
        if scenario.station.control_mode == "position":
            builder.ExportInput(self.interface.GetInputPort("joint_position_command"), "joint_position_command")
            builder.ExportInput(self.interface.GetInputPort("joint_velocity_command"), "joint_velocity_command")
        for name in CONTROLLER_OUTPUTS:
            builder.ExportOutput(self.interface.GetOutputPort(name), name)
        builder.ExportOutput(unknown.get_output_port(), "trunk_contact")
        builder.BuildInto(self)
        self.set_name("station")

    def station_metrics(self, root_context) -> dict:
        """The interface's counters and its safe stop, or the driver's as its status reports it."""
        interface = self.interface.counters(root_context)
        stop = first_safe_stop({"interface": interface})
        if not stop and interface["driver_safe_stop"]:
            stop = "reported by the robot driver (its own report says why)"
        return {"lcm_interface": interface, "trunk_contact_observed": False, "safe_stop": stop}


def make_remote_lcm_station(scenario: Scenario, meshcat=None, *, mesh_dir=None, lcm_url: str,
                            config: HardwareConfig | None = None):
    """A make_station-compatible factory: (RemoteLcmStation, StationInfo) on ``lcm_url``."""
    station = RemoteLcmStation(scenario=scenario, lcm=connect_lcm(lcm_url), config=config)
    return station, station.info
