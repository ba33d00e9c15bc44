"""Station and controller in one DiagramBuilder: Qingzhui holds its standing pose.

The simulation station (``make_station``: a MultibodyPlant of the robot on its terrain, with
sensors) is a Diagram with named ports. The joint PD of paper 000 Eq. 7 (``JointPdController``)
reads the station's ``state`` and writes its ``joint_torque``; two constant sources give it the
standing pose to hold and each foot's share of the body weight to push with. A Simulator runs
the diagram, a logger on ``state`` records the trunk, and the example judges the stand: the
trunk must stay within the scenario's ``success.max_base_height_error`` of where it started.

Run (writes recording.html, a meshcat recording to open in a browser, under --out):

    .venv/bin/python examples/station_and_controller.py [--duration 3] [--out DIR]

Change the terrain (``TerrainConfig(kind="stairs")``), the gains or the pose, and run it again.
"""

import argparse
import sys
from pathlib import Path

import numpy as np
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import ConstantVectorSource, LogVectorOutput

from qz_drake.config import Scenario, TerrainConfig
from qz_drake.station import GRAVITY, make_station
from qz_drake.state_layout import BASE_Z, JOINT_Q, tilt_deg
from qz_drake.systems.joint_pd import JointPdController
from qz_drake.viz.recording import recording_meshcat, save_recording


def add_standing_controller(builder, station, info, *, kp, kd):
    """Adds the joint PD holding the standing pose of ``info`` and connects it to the station's
    ``state`` and ``joint_torque`` ports; returns the controller."""
    controller = builder.AddSystem(JointPdController(kp=kp, kd=kd, params=info.params))
    # Desired state: the joint angles the station started in, at rest.
    q_standing = info.initial_state[JOINT_Q]
    pose = builder.AddSystem(ConstantVectorSource(np.concatenate([q_standing, np.zeros(18)])))
    # Each of the six feet carries a sixth of the weight, so the PD corrects only errors.
    weight = info.params.total_mass * GRAVITY
    push = builder.AddSystem(ConstantVectorSource(np.tile([0.0, 0.0, weight / 6.0], 6)))
    builder.Connect(station.GetOutputPort("state"), controller.GetInputPort("state"))
    builder.Connect(pose.get_output_port(), controller.GetInputPort("desired_state"))
    builder.Connect(push.get_output_port(), controller.GetInputPort("foot_force_feedforward"))
    builder.Connect(controller.GetOutputPort("joint_torque"), station.GetInputPort("joint_torque"))
    return controller


def port_names(system) -> str:
    inputs = [system.get_input_port(i).get_name() for i in range(system.num_input_ports())]
    outputs = [system.get_output_port(i).get_name() for i in range(system.num_output_ports())]
    return f"in: {', '.join(inputs)}; out: {', '.join(outputs)}"


def stand_and_judge(builder, station, scenario, duration, out, meshcat):
    """Logs the station's ``state``, builds the diagram, simulates ``duration`` seconds, writes
    the recording and prints the judgement; returns (whether the robot stood, the Simulator)."""
    logger = LogVectorOutput(station.GetOutputPort("state"), builder, 0.01)
    diagram = builder.Build()
    simulator = Simulator(diagram)
    simulator.Initialize()
    meshcat.StartRecording()
    simulator.AdvanceTo(duration)
    meshcat.StopRecording()
    recording = save_recording(meshcat, Path(out) / "recording.html", follow_robot=True)

    states = logger.FindLog(simulator.get_context()).data().T
    heights = states[:, BASE_Z]
    change = float(np.max(np.abs(heights - heights[0])))
    tilt = max(tilt_deg(x) for x in states)
    stood = change <= scenario.success.max_base_height_error
    print(f"trunk height {heights[0]:.3f} m -> {heights[-1]:.3f} m after {duration:g} s "
          f"(largest change {change * 1000:.1f} mm), largest tilt {tilt:.2f} deg")
    print(f"{'stood' if stood else 'FAILED to stand'}; recording: {recording}")
    return stood, simulator


def standing_arguments(doc: str, name: str):
    """The command line of a standing example: --duration, and --out (created)."""
    parser = argparse.ArgumentParser(description=doc.split("\n")[0])
    parser.add_argument("--duration", type=float, default=3.0, help="simulated time [s]")
    parser.add_argument("--out", default=f"out/examples/{name}", help="output folder")
    args = parser.parse_args()
    Path(args.out).mkdir(parents=True, exist_ok=True)
    return args


def main() -> int:
    args = standing_arguments(__doc__, "station_and_controller")
    # Flat concrete as box contact: the quickest ground to simulate.
    scenario = Scenario(name="stand_flat", terrain=TerrainConfig(kind="flat", contact="boxes"))
    meshcat = recording_meshcat()
    builder = DiagramBuilder()
    station_diagram, info = make_station(scenario, meshcat)
    station = builder.AddSystem(station_diagram)
    # The first input and four outputs are what a controller may use (the LCM station has just
    # those); the rest are the simulation's truth, for monitors and metrics.
    print(f"simulation station, {port_names(station)}")
    add_standing_controller(builder, station, info, kp=scenario.controller.kp, kd=scenario.controller.kd)
    stood, _ = stand_and_judge(builder, station, scenario, args.duration, args.out, meshcat)
    return 0 if stood else 1


if __name__ == "__main__":
    sys.exit(main())
