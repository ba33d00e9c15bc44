"""The LCM protocol's settings, shared by the interface and the (simulated) robot driver.

One typed dataclass with a YAML form (``load_hardware_config``), defaults in one place. The
timing of one control period ``h`` (both sides use the same period, each on its own clock)::

    driver:     0       physics / servo tick: applies the latched command
                h/16    publishes qz_status (and qz_pose) measured after the tick
    interface:  h/2     decodes the newest status, runs the watchdog and the estimator
                3h/4    publishes qz_command computed from that status
    driver:     15h/16  checks and latches the newest command for the next tick

so a command reaches the driver before its next tick: the status-to-command budget is 7h/8,
and in the lockstep simulation the controller sees the same measurement at the same tick as
against the simulation station. A servo in another process (qz_drake.hardware.servo) answers
a status as soon as it comes, not at 3h/4 of a clock of its own.
"""

# (No "from __future__ import annotations": pydrake.common.yaml reads the field types.)
import dataclasses
import math

from pydrake.common.yaml import yaml_load_typed

from qz_drake.errors import ConfigError, bad_value


@dataclasses.dataclass
class ChannelConfig:
    # Robot -> controller: qz_status at the control rate.
    status: str = "QZ_STATUS"
    # Controller -> robot: qz_command at the control rate.
    command: str = "QZ_COMMAND"
    # Localisation -> controller: qz_pose (base position and velocity in the map).
    pose: str = "QZ_POSE"
    # Planning process -> servo: qz_reference tables, one per plan (qz_drake.hardware.servo).
    reference: str = "QZ_REFERENCE"
    # Planning process -> servo: qz_planner heartbeats.
    planner: str = "QZ_PLANNER"
    # Servo -> planning process: qz_servo, every fifth control period.
    servo: str = "QZ_SERVO"


@dataclasses.dataclass
class HardwareConfig:
    channels: ChannelConfig = dataclasses.field(default_factory=ChannelConfig)
    # The control period of status and command messages; the plant step of the simulated
    # driver (500 Hz: the joint PD of Eq. 7 runs at every step, as in the simulation). [s]
    control_period: float = 0.002
    # Localisation (qz_pose) period of the simulated driver; LiDAR odometry runs at ~10 Hz. [s]
    pose_period: float = 0.002
    # The time budget of a link: a status (interface side) or command (driver side) older than
    # this latches a safe stop; until then the last good one is held and lost ones are only
    # counted. 10.5 periods: the eleventh missing message trips it. Two processes on this
    # 2-core machine, busy with other work, went up to 9 periods without a command at
    # --realtime-rate 0.5 (6 at 0.1) and lost up to 7 statuses in a row in walks that
    # succeeded, where the former 2.5 periods stopped walks within a second (a process held
    # off the CPU for longer still latches: README). In 21 ms the trunk moves 5 mm at the
    # walking speed, and a status outage during a tripod swing let the robot sink 0.7 cm (the
    # interface repeating its last command through the budget, then the safe stop's hold). [s]
    status_timeout: float = 0.021
    command_timeout: float = 0.021
    # (There is no limit on messages lost in a row, the former max_missed_messages: the age is
    # checked every period, so a burst longer than the budget is a stale link anyway, and a
    # shorter one is what the budget allows.)
    # The sender's clock may advance differently from the receiver's by this much between two
    # messages before it counts as a clock jump (network jitter stays well below it; an end
    # that fell this far behind the other sees the same). [s]
    clock_tolerance: float = 0.02
    # A measured joint angle this far outside the joint limits marks a malformed status. [rad]
    joint_limit_margin: float = 0.05
    # A pose is not extrapolated further than this (localisation drop-outs). [s]
    max_pose_extrapolation: float = 0.2
    # Driver safe stop in torque mode: hold the joint angles measured when the stop began with
    # this PD (position mode: the drives' own PD holds them). [N*m/rad], [N*m*s/rad]
    safe_stop_kp: float = 1000.0
    safe_stop_kd: float = 20.0
    # The servo latches a safe stop when the planning process's heartbeat has been silent this
    # long (a process that exited or hung). Its heartbeat comes from a thread of its own every
    # PLANNER_HEARTBEAT_PERIOD, also while it solves; a single compiled call that holds the
    # interpreter (a value iteration over a large map) can delay it by a second or more, and a
    # late plan only makes the robot stand, so the budget is generous. [s]
    planner_timeout: float = 2.0
    # The planning process runs its simulation at most this far ahead of the servo's plan
    # clock: a mission starts this much earlier than on the lockstep clock, at most. [s]
    plan_lead: float = 0.05


def validate_hardware_config(config: HardwareConfig) -> HardwareConfig:
    """Checks values the YAML types cannot; returns the config."""
    for name in ("control_period", "pose_period", "status_timeout", "command_timeout",
                 "clock_tolerance", "max_pose_extrapolation", "safe_stop_kp", "safe_stop_kd", "planner_timeout",
                 "plan_lead"):
        value = getattr(config, name)
        if not (math.isfinite(value) and value > 0):
            raise bad_value(f"hardware.{name}", value, "must be a finite positive number")
    if config.status_timeout <= config.control_period or config.command_timeout <= config.control_period:
        raise bad_value("hardware.status_timeout", config.status_timeout,
                        f"must exceed one control period ({config.control_period} s)")
    if config.joint_limit_margin < 0:
        raise bad_value("hardware.joint_limit_margin", config.joint_limit_margin, "must be >= 0")
    for name in ("status", "command", "pose", "reference", "planner", "servo"):
        if not getattr(config.channels, name):
            raise bad_value(f"hardware.channels.{name}", "", "a channel needs a name")
    return config


def load_hardware_config(text: str) -> HardwareConfig:
    """A HardwareConfig from YAML text (fields not given keep their defaults)."""
    try:
        config = yaml_load_typed(schema=HardwareConfig, data=text or "{}")
    except (RuntimeError, ValueError, TypeError) as e:
        raise ConfigError(f"hardware config: {e}") from None
    return validate_hardware_config(config)
