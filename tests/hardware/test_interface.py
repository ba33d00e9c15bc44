"""The LCM station against the simulated robot driver over memq://: ports, standing, faults.

Every run is the lockstep diagram of qz_drake.hardware.loopback (deterministic, no real-time
pacing). Faults are injected by the message hooks of the driver (status) and the interface
(command); the assertions are on counters, latch times and the robot's motion.
"""

import math

import numpy as np
import pytest
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder

from qz_drake.config import Scenario
from qz_drake.errors import ConfigError
from qz_drake.hardware import driver as driver_module
from qz_drake.hardware.config import HardwareConfig, load_hardware_config
from qz_drake.hardware.loopback import make_lcm_loopback_station
from qz_drake.simulation import _standing_controller
from qz_drake.station import make_station
from qz_drake.state_layout import IMU_SIZE, STATE_SIZE, tilt_deg

H = HardwareConfig().control_period
CONTROLLER_PORTS = {"state": STATE_SIZE, "joint_torque_measured": 18, "imu": IMU_SIZE, "foot_contact": 6}


def _port_names(system, kind):
    count = system.num_input_ports() if kind == "in" else system.num_output_ports()
    get = system.get_input_port if kind == "in" else system.get_output_port
    return {get(i).get_name(): get(i).size() if get(i).get_data_type().name == "kVectorValued" else None
            for i in range(count)}


@pytest.mark.parametrize("mode", ["torque", "position"])
def test_lcm_station_exports_exactly_the_controller_ports_of_the_simulation(mode):
    scenario = Scenario()
    scenario.station.control_mode = mode
    sim, _ = make_station(scenario)
    lcm, info = make_station(scenario, backend="lcm", lcm_url="memq://")
    assert _port_names(lcm, "in") == _port_names(sim, "in")
    outputs = _port_names(lcm, "out")
    assert outputs == CONTROLLER_PORTS
    assert all(_port_names(sim, "out")[name] == size for name, size in outputs.items())
    assert info.contact_representation == "lcm"
    np.testing.assert_allclose(info.initial_state, make_station(scenario)[1].initial_state)


def test_unknown_backend_and_bad_config_name_the_field():
    with pytest.raises(ConfigError, match="backend = 'ros'"):
        make_station(Scenario(), backend="ros")
    with pytest.raises(ConfigError, match="hardware.status_timeout"):
        load_hardware_config("status_timeout: 0.001")
    assert load_hardware_config("channels: {status: ROBOT_STATUS}").channels.status == "ROBOT_STATUS"


def stand(duration, scenario=None, **options):
    """Qingzhui standing under joint PD through the LCM station; returns (simulator, station)."""
    scenario = scenario or Scenario()
    builder = DiagramBuilder()
    diagram, info = make_lcm_loopback_station(scenario, **options)
    station = builder.AddSystem(diagram)
    _standing_controller(builder, station, info, scenario)
    simulator = Simulator(builder.Build())
    simulator.AdvanceTo(duration)
    return simulator, station


def test_standing_through_lcm_matches_the_simulation():
    simulator, station = stand(1.0)
    context = station.GetMyContextFromRoot(simulator.get_context())
    over_lcm = station.GetOutputPort("true_state").Eval(context)
    estimate = station.GetOutputPort("state").Eval(context)
    builder = DiagramBuilder()
    sim, info = make_station(Scenario())
    sim = builder.AddSystem(sim)
    _standing_controller(builder, sim, info, Scenario())
    direct = Simulator(builder.Build())
    direct.AdvanceTo(1.0)
    truth = sim.GetOutputPort("state").Eval(sim.GetMyContextFromRoot(direct.get_context()))
    # The driver's first tick holds (no command yet): a transient of well under a millimetre.
    np.testing.assert_allclose(over_lcm[:25], truth[:25], atol=1e-3)
    # The estimate (IMU orientation, encoders, pose topic) is the measurement of the tick before.
    np.testing.assert_allclose(estimate[:25], over_lcm[:25], atol=1e-3)
    counters = station.station_metrics(simulator.get_context())
    assert counters["lcm_interface"]["received"] == 500 and counters["lcm_interface"]["safe_stops"] == 0
    assert counters["lcm_driver"]["received"] == 500 and counters["lcm_driver"]["safe_stops"] == 0


def faulty_status(k, fault):
    """A status hook applying ``fault(message)`` to the message of sequence k."""
    def hook(m):
        return fault(m) if m.sequence == k else m
    return hook


def test_a_nan_in_one_status_is_rejected_counted_and_stops_safely():
    def nan(m):
        m.joint_velocity[4] = float("nan")
        return m
    simulator, station = stand(0.4, status_filter=faulty_status(100, nan))
    root = simulator.get_context()
    interface = station.station_metrics(root)["lcm_interface"]
    assert interface["rejected"] == 1 and interface["received"] == 200 and interface["safe_stops"] == 1
    assert "joint_velocity[4] = nan" in interface["safe_stop_reason"]
    # Status 100 was published at 99.25 periods and checked half a period later.
    assert interface["safe_stop_time_s"] == pytest.approx(99.5 * H)
    # The estimate never saw the NaN; the driver holds (commanded safe stop) and the robot stands.
    context = station.GetMyContextFromRoot(root)
    assert np.all(np.isfinite(station.GetOutputPort("state").Eval(context)))
    driver = station.station_metrics(root)["lcm_driver"]
    assert driver["holding"] and not driver["safe_stop_latched"] and interface["driver_safe_stop"]
    x = station.GetOutputPort("true_state").Eval(context)
    assert abs(x[6] - 0.55) < 0.02 and tilt_deg(x) < 2.0


def test_a_jump_of_the_drivers_clock_is_detected():
    def jump(m):
        if m.sequence >= 100:
            m.utime += 250_000
        return m
    simulator, station = stand(0.3, status_filter=jump)
    interface = station.station_metrics(simulator.get_context())["lcm_interface"]
    assert interface["clock_jumps"] == 1 and interface["safe_stops"] == 1
    assert "clock jumped by +0.25" in interface["safe_stop_reason"]


def test_a_duplicated_sequence_number_is_detected():
    def repeat(m):
        m.sequence = 99
        return m
    simulator, station = stand(0.3, status_filter=faulty_status(100, repeat))
    interface = station.station_metrics(simulator.get_context())["lcm_interface"]
    assert interface["duplicates"] == 1 and interface["missed"] == 1 and interface["sequence_jumps"] == 0
    assert interface["safe_stop_reason"] == "status sequence number 99 repeated"


def test_an_out_of_limit_torque_is_clamped_and_counted():
    seen = []

    def spike(m):
        if m.sequence == 100:
            m.joint_torque[1] = 1e4
        return m

    def record(m):
        seen.append(list(m.joint_torque))
        return m
    simulator, station = stand(0.3, command_filter=spike, status_filter=record)
    driver = station.station_metrics(simulator.get_context())["lcm_driver"]
    assert driver["clamped_commands"] == 1 and driver["clamped_torques"] == 1
    assert driver["safe_stops"] == 0 and driver["rejected"] == 0
    measured = np.array(seen)
    assert np.abs(measured).max() == pytest.approx(250.0)
    assert np.count_nonzero(np.isclose(measured[:, 1], 250.0)) == 1


def test_a_stale_or_malformed_command_latches_the_drivers_safe_stop():
    last = {}

    def freeze(m):  # from command 100 on, the same message again: silence to the driver
        if m.sequence < 100:
            last["m"] = m
        return last["m"]
    simulator, station = stand(0.3, command_filter=freeze)
    root = simulator.get_context()
    driver = station.station_metrics(root)["lcm_driver"]
    assert driver["stale"] == 1 and driver["safe_stop_latched"] and driver["holding"]
    # Command 99 was taken in at 98 periods and the driver's command phase; the first check at
    # which it is older than the budget latches, and says so.
    timeout = HardwareConfig().command_timeout
    taken_in = 98 + driver_module.COMMAND_PHASE
    assert driver["safe_stop_time_s"] == pytest.approx((taken_in + math.floor(timeout / H) + 1) * H)
    assert driver["safe_stop_reason"] == (f"command stale for {(math.floor(timeout / H) + 1) * H * 1e3:.1f} ms "
                                          f"(timeout {timeout * 1e3:.1f} ms)")
    assert station.station_metrics(root)["lcm_interface"]["driver_safe_stop"]

    def nan(m):
        if m.sequence == 100:
            m.joint_torque[0] = float("nan")
        return m
    simulator, station = stand(0.3, command_filter=nan)
    driver = station.station_metrics(simulator.get_context())["lcm_driver"]
    assert driver["rejected"] == 1 and driver["safe_stop_latched"] and "joint_torque[0] = nan" in driver[
        "safe_stop_reason"]


def test_lost_statuses_are_counted_and_ridden_through():
    """UDP loses a few statuses: the interface holds the last good one, counts the gaps, and the
    controller and the driver carry on without a safe stop."""
    lost = {100, 101, 102, 103, 200}
    commands = {}

    def record(m):
        commands[m.sequence] = m
        return m
    simulator, station = stand(0.5, status_filter=lambda m: None if m.sequence in lost else m,
                               command_filter=record)
    root = simulator.get_context()
    interface = station.station_metrics(root)["lcm_interface"]
    assert interface["missed"] == 5 and interface["gaps"] == 2 and interface["longest_gap"] == 4
    assert interface["received"] == 250 - 5 and interface["safe_stops"] == 0 and interface["stale"] == 0
    assert not interface["safe_stop_latched"] and not interface["driver_safe_stop"]
    assert station.station_metrics(root)["safe_stop"] == ""
    driver = station.station_metrics(root)["lcm_driver"]
    assert not driver["holding"] and driver["safe_stops"] == 0
    x = station.GetOutputPort("true_state").Eval(station.GetMyContextFromRoot(root))
    assert abs(x[6] - 0.55) < 0.01 and tilt_deg(x) < 1.0
    # Command k answers status k; while statuses were missing, the command that answered the
    # last one came again (a fresh sequence number, the same joints).
    assert [commands[k].status_sequence for k in range(98, 106)] == [98, 99, 99, 99, 99, 99, 104, 105]
    assert all(list(commands[k].joint_torque) == list(commands[99].joint_torque) for k in range(100, 104))
    assert list(commands[104].joint_torque) != list(commands[99].joint_torque)


def test_reset_resumes_after_a_status_outage():
    drop = lambda m: None if 100 <= m.sequence < 125 else m  # noqa: E731
    simulator, station = stand(0.3, status_filter=drop)
    root = simulator.get_context()
    assert station.interface.watchdog(root).latched
    # Status 99 was taken in at 98.5 periods; stale at the first check past the budget.
    timeout = HardwareConfig().status_timeout
    checks = math.floor(timeout / H) + 1
    metrics = station.station_metrics(root)
    assert metrics["lcm_interface"]["safe_stop_reason"] == (f"status stale for {checks * H * 1e3:.1f} ms "
                                                            f"(timeout {timeout * 1e3:.1f} ms)")
    assert metrics["safe_stop"] == f"at {(98.5 + checks) * H:.3f} s on the interface: " + \
        metrics["lcm_interface"]["safe_stop_reason"]
    station.interface.reset_safe_stop(root)
    simulator.AdvanceTo(0.4)
    interface = station.station_metrics(root)["lcm_interface"]
    assert not interface["safe_stop_latched"] and interface["safe_stops"] == 1 and interface["stale"] == 1
    assert not station.station_metrics(root)["lcm_driver"]["holding"]


def test_the_remote_station_has_the_logged_ports_and_says_trunk_contact_is_unobserved():
    from qz_drake.hardware.loopback import make_remote_lcm_station

    station, info = make_remote_lcm_station(Scenario(), lcm_url="memq://")
    assert set(_port_names(station, "out")) == set(CONTROLLER_PORTS) | {"trunk_contact"}
    context = station.CreateDefaultContext()
    station.GetInputPort("joint_torque").FixValue(context, np.zeros(18))
    assert np.isnan(station.GetOutputPort("trunk_contact").Eval(context)[0])
    # Before the first status: the expected standing start, and safe-stop commands.
    np.testing.assert_allclose(station.GetOutputPort("state").Eval(context), info.initial_state)
    assert station.station_metrics(context)["trunk_contact_observed"] is False


def test_a_slow_localisation_is_extrapolated_and_a_missing_one_counted():
    """Poses at 10 Hz: between them the base position is carried forward by the pose's velocity;
    with the pose topic silent the statuses are counted as decoded with a stale pose."""
    simulator, station = stand(0.3, config=HardwareConfig(pose_period=0.1))
    counters = station.station_metrics(simulator.get_context())["lcm_interface"]
    assert counters["pose_received"] == 3 and counters["pose_stale"] == 0 and counters["safe_stops"] == 0
    simulator, station = stand(0.3, pose_filter=lambda m: None)
    counters = station.station_metrics(simulator.get_context())["lcm_interface"]
    assert counters["pose_received"] == 0 and counters["pose_stale"] == 150 and counters["safe_stops"] == 0
    # Without a pose the base position stays the expected start.
    context = station.GetMyContextFromRoot(simulator.get_context())
    np.testing.assert_allclose(station.GetOutputPort("state").Eval(context)[4:7], [0.0, 0.0, 0.55], atol=1e-9)


def test_a_message_of_the_wrong_type_on_the_status_channel_is_rejected_once():
    from qz_drake.hardware.qz_lcm import qz_pose

    simulator, station = stand(0.3, status_filter=faulty_status(100, lambda m: qz_pose()))
    interface = station.station_metrics(simulator.get_context())["lcm_interface"]
    assert interface["rejected"] == 1 and interface["received"] == 150 and interface["missed"] == 1
    assert "not a qz_status" in interface["safe_stop_reason"]
