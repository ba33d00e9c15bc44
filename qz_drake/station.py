"""The station: the simulated robot or the real one behind the same ports (DESIGN.md).

``make_station(scenario, meshcat, backend=...)`` returns (diagram, StationInfo): the
MultibodyPlant station of qz_drake.sim_station, or the LCM QingzhuiHardwareInterface of
qz_drake.hardware.interface, with the same controller ports. Controllers are added by the
caller (see qz_drake.simulation).
"""

from __future__ import annotations

from pathlib import Path

from pydrake.geometry import Meshcat
from pydrake.systems.framework import Diagram

from qz_drake.config import Scenario
from qz_drake.errors import bad_value
from qz_drake.hardware.interface import make_hardware_interface
# The scene's pieces, also imported from here (notebooks, benchmarks, cli/blc.py).
from qz_drake.scene import GRAVITY, StationInfo, make_heightmap, standing_state  # noqa: F401
from qz_drake.sim_station import make_sim_station


def make_station(scenario: Scenario, meshcat: Meshcat | None = None, *,
                 mesh_dir: str | Path | None = None, heightmap=None, backend: str = "sim",
                 lcm_url: str = "memq://", hardware=None) -> tuple[Diagram, StationInfo]:
    """Builds the station for a scenario; returns (diagram, info).

    ``backend="sim"``: the MultibodyPlant station (make_sim_station); ``heightmap`` then replaces the
    scenario's terrain section's map (e.g. a capability scene held in memory); the section's
    contact, material and region still apply. ``backend="lcm"``: the
    QingzhuiHardwareInterface (qz_drake.hardware) with the same controller ports, talking LCM
    on ``lcm_url`` to a robot driver (the robot, or ``qz robot-sim``), with ``hardware`` (a
    qz_drake.hardware.config.HardwareConfig) as its protocol settings.
    """
    if backend == "lcm":
        if heightmap is not None:
            raise bad_value("heightmap", "a HeightMap", "replaces the simulated terrain: backend 'sim' only")
        return make_hardware_interface(scenario, meshcat, lcm_url=lcm_url, config=hardware)
    if backend != "sim":
        raise bad_value("backend", backend, "expected sim or lcm")
    return make_sim_station(scenario, meshcat, mesh_dir=mesh_dir, heightmap=heightmap)
