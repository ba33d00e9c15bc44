"""One controller factory, two stations: walking through the LCM interface and its safe stop.

The walks run simulate() with the simulation station and with the LCM loopback (interface +
simulated robot driver over memq://): the same controller code (add_tracking_controller and
the mission sequencer) builds both diagrams.
"""

import functools
import json
from pathlib import Path

import numpy as np
import pytest

from qz_drake.cli import main
from qz_drake.config import ControllerConfig, Scenario, Waypoint, load_scenario
from qz_drake.hardware.config import HardwareConfig
from qz_drake.hardware.driver import STATUS_PHASE
from qz_drake.hardware.loopback import make_lcm_loopback_station
from qz_drake.simulation import simulate
from qz_drake.state_layout import tilt_deg

SCENARIOS = Path(__file__).resolve().parents[2] / "scenarios"
H = HardwareConfig().control_period


@pytest.mark.slow
@pytest.mark.parametrize("mode", ["position", "torque"])
def test_walk_flat_through_lcm_tracks_like_the_simulation(mode):
    scenario = load_scenario(SCENARIOS / "walk_flat.yaml")
    scenario.station.control_mode = mode
    direct = simulate(scenario).metrics
    over_lcm = simulate(scenario, station_factory=make_lcm_loopback_station).metrics
    assert direct["success"], direct
    assert over_lcm["success"], over_lcm
    assert abs(over_lcm["tracking_rms_m"] - direct["tracking_rms_m"]) < 0.01
    assert over_lcm["tracking_rms_m"] < 0.05 and over_lcm["final_xy_error_m"] < 0.15
    interface, driver = over_lcm["lcm_interface"], over_lcm["lcm_driver"]
    steps = round(over_lcm["sim_time_s"] / H)
    assert interface["received"] == steps and interface["safe_stops"] == 0 and interface["rejected"] == 0
    assert driver["received"] == steps and driver["safe_stops"] == 0 and driver["clamped_commands"] == 0


# The status stops for 50 ms from here, while a tripod swings. [s]
OUTAGE_START = 1.3


def test_status_outage_while_walking_latches_a_safe_stop_and_the_robot_stands():
    scenario = Scenario(name="walk_outage", controller=ControllerConfig(kind="walk", route=[Waypoint(x=1.0)]))
    scenario.simulation.duration = OUTAGE_START + 1.5
    first_missing = round(OUTAGE_START / H) + 1  # the sequence number of the status at OUTAGE_START

    def outage(m):
        return None if first_missing <= m.sequence < first_missing + round(0.05 / H) else m
    factory = functools.partial(make_lcm_loopback_station, status_filter=outage)
    result = simulate(scenario, station_factory=factory)
    interface = result.metrics["lcm_interface"]
    assert interface["stale"] == 1 and interface["safe_stops"] == 1 and interface["safe_stop_latched"]
    # Latched at the first check at which the last status was older than the budget: within a
    # period of the budget after the first missing status would have come (the driver's status
    # phase past its tick).
    missing_at = (first_missing - 1 + STATUS_PHASE) * H
    timeout = HardwareConfig().status_timeout
    assert timeout - H < interface["safe_stop_time_s"] - missing_at <= timeout + H
    # The walk's outcome names the safe stop and its cause before the missed target.
    assert result.metrics["reason"].startswith(
        f"safe stop at {interface['safe_stop_time_s']:.3f} s on the interface: status stale for ")
    assert result.metrics["reasons"][0] == "safe_stop" and "missed_target" in result.metrics["reasons"]
    # The driver held from the first safe-stop command; the robot stays up.
    assert result.metrics["lcm_driver"]["holding"] and interface["driver_safe_stop"]
    before = result.states[np.searchsorted(result.times, OUTAGE_START), 6]
    after = result.states[result.times > OUTAGE_START, 6]
    # Through the status budget the interface sends the last good command again (0.7 cm;
    # recomputing it against the frozen measurement: 3.8 cm), then the hold's compliance.
    assert before - after.min() < 0.015
    assert max(tilt_deg(x) for x in result.states) < 5.0
    assert result.metrics["trunk_terrain_contacts"] == 0


def test_qz_simulate_with_the_lcm_station(tmp_path, capsys):
    path = tmp_path / "stand.yaml"
    path.write_text("name: stand\nsimulation: {duration: 0.5}\n")
    code = main(["simulate", str(path), "--station", "lcm", "--out", str(tmp_path / "o")])
    metrics = json.loads(capsys.readouterr().out)
    assert code == 0 and metrics["success"], metrics
    assert metrics["lcm_interface"]["received"] == 250 and metrics["lcm_driver"]["safe_stops"] == 0
    assert json.loads((tmp_path / "o" / "metrics.json").read_text())["lcm_interface"]["rejected"] == 0


def test_qz_robot_sim_holds_without_a_controller(tmp_path, capsys):
    code = main(["robot-sim", str(SCENARIOS / "walk_flat.yaml"), "--lcm-url", "memq://", "--duration", "0.5",
                 "--realtime-rate", "0"])
    report = json.loads(capsys.readouterr().out)
    assert code == 0 and report["holding"] and report["received"] == 0 and not report["safe_stop_latched"]
    # It says how it was scheduled (normal, at nice -20 where allowed), what its collector did
    # after the setup, and the longest wall time between two statuses it sent.
    assert report["scheduling"].startswith("normal, nice ") and report["gc_collections"] >= 0
    assert report["statuses_published"] == 250 and report["longest_publish_gap_ms"] > 0
    # Held by the safe-stop PD alone (no gravity compensation): it sinks by millimetres.
    assert 0.535 < report["base_position_m"][2] < 0.551
    assert main(["robot-sim", str(SCENARIOS / "walk_flat.yaml"), "--duration", "-1"]) == 2
