"""The LCM station: the controller of station_and_controller.py, talking to the robot over LCM.

``make_station(scenario, meshcat, backend="lcm", lcm_url=...)`` returns
QingzhuiHardwareInterface in place of the simulation station: LCM subscribers and a publisher
behind exactly the same ports (``joint_torque`` in; ``state``, ``joint_torque_measured``,
``imu``, ``foot_contact`` out). Against the real robot that is the whole diagram. Here the
robot is the simulated robot driver (QingzhuiRobotDriver, what ``qz robot-sim`` runs): the
simulation station behind the LCM protocol, added to the same diagram on the same in-process
LCM (``memq://``: deterministic, no network). Only the station changed: the standing
controller, the logger and the judgement are station_and_controller.py's.

Run (writes recording.html, drawn from the driver's simulation, under --out):

    .venv/bin/python examples/lcm_station.py [--duration 3] [--out DIR]

Against a driver in another process (``qz robot-sim`` or the robot) give its URL to
``make_station`` instead, drop the driver from the diagram and pace the Simulator to real time.
"""

import sys

from pydrake.systems.framework import DiagramBuilder

from qz_drake.config import Scenario, TerrainConfig
from qz_drake.hardware.driver import QingzhuiRobotDriver
from qz_drake.station import make_station
from qz_drake.viz.recording import recording_meshcat
from station_and_controller import add_standing_controller, port_names, stand_and_judge, standing_arguments


def main() -> int:
    args = standing_arguments(__doc__, "lcm_station")
    scenario = Scenario(name="stand_flat", terrain=TerrainConfig(kind="flat", contact="boxes"))
    meshcat = recording_meshcat()
    builder = DiagramBuilder()
    # What differs from station_and_controller.py: the station's backend, ...
    station_diagram, info = make_station(scenario, meshcat, backend="lcm", lcm_url="memq://")
    station = builder.AddSystem(station_diagram)
    print(f"LCM station ({type(station_diagram).__name__}), {port_names(station)}")
    # ... and the robot at the link's other end. An in-process LCM reaches only the DrakeLcm
    # it was made on, so the driver shares the interface's.
    builder.AddSystem(QingzhuiRobotDriver(scenario=scenario, lcm=station_diagram.lcm, meshcat=meshcat))
    add_standing_controller(builder, station, info, kp=scenario.controller.kp, kd=scenario.controller.kd)
    stood, simulator = stand_and_judge(builder, station, scenario, args.duration, args.out, meshcat)

    # What crossed the link, as the interface counted it (the metrics of `qz simulate --station lcm`).
    link = station_diagram.counters(simulator.get_context())
    print(f"LCM statuses received {link['received']}, missed {link['missed']}, rejected {link['rejected']}; "
          f"safe stop: {link['safe_stop_reason'] or 'none'}")
    return 0 if stood and not link["safe_stop_latched"] else 1


if __name__ == "__main__":
    sys.exit(main())
