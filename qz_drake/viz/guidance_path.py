"""CapPlanner's guidance path in meshcat (paper 000 Fig. 6-8, issue 14): the missions the TLC
planned, drawn over the terrain and replaced at every replan, also in recordings.

Each guidance (the list of GuidedMissions the CapabilityVIPlanner outputs) is drawn once, when
it changes, as one polyline per mission through the cells its actions cross, a little above the
ground and coloured by the mission's topology, with a marker at the mission's target. In a
recording, guidance k is visible from the time it was planned until the next replan: a replay
shows the plan the robot was following at each moment.
"""

from __future__ import annotations

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.geometry import Rgba, Sphere
from pydrake.math import RigidTransform
from pydrake.systems.framework import LeafSystem

# One colour per topology (paper 000's six); unknown names are grey.
TOPOLOGY_COLOURS = {
    "nominal": Rgba(0.85, 0.1, 0.1, 1.0),
    "hind_bend": Rgba(0.1, 0.45, 0.9, 1.0),
    "front_bend": Rgba(0.1, 0.7, 0.3, 1.0),
    "hind_1_bend": Rgba(0.6, 0.2, 0.8, 1.0),
    "front_1_bend": Rgba(0.95, 0.55, 0.1, 1.0),
    "split_up": Rgba(0.1, 0.75, 0.75, 1.0),
}
# Height of the drawn path above the terrain. [m]
LIFT = 0.05
ROOT = "/capplanner/guidance"


def mission_polyline(mission) -> np.ndarray:
    """(N, 2) x, y of the cell centres a GuidedMission's actions cross, in order."""
    from qz_drake.planning.guidance import _after

    points = [(mission.steps[0].x, mission.steps[0].y)] if mission.steps else \
        [tuple(mission.target[:2])]
    for step in mission.steps:
        x, y, _ = _after(step)
        if (x, y) != points[-1]:
            points.append((x, y))
    return np.asarray(points, dtype=float)


class GuidancePathVisualizer(LeafSystem):
    """Draws the guidance path in meshcat whenever it changes.

    .. pydrake_system::

        name: GuidancePathVisualizer
        input_ports:
        - guidance

    Args:
        meshcat: the Meshcat to draw in (its recording, when one is running, gets the
            visibility of each guidance over time).
        heightmap: the terrain (HeightMap), for the heights the path is drawn at.
        period: how often the input is checked. [s]
    """

    def __init__(self, *, meshcat, heightmap, period: float = 0.1):
        super().__init__()
        self._meshcat = meshcat
        self._heightmap = heightmap
        self._guidance = self.DeclareAbstractInputPort("guidance", AbstractValue.Make([]))
        self.DeclarePeriodicPublishEvent(period, 0.0, self._publish)
        self.DeclareInitializationPublishEvent(self._publish)
        self._drawn = None
        # Paths drawn so far (guidance k at ROOT/k).
        self.count = 0

    def _publish(self, context):
        missions = list(self._guidance.Eval(context))
        key = tuple((tuple(np.round(m.target, 6)), m.topology, len(m.steps)) for m in missions)
        if not missions or key == self._drawn:
            return
        t = context.get_time()
        meshcat = self._meshcat
        if self.count:
            meshcat.SetProperty(f"{ROOT}/{self.count - 1}", "visible", False, t)
        path = f"{ROOT}/{self.count}"
        for i, mission in enumerate(missions):
            xy = mission_polyline(mission)
            z = np.asarray(self._heightmap.height(xy[:, 0], xy[:, 1]), dtype=float) + LIFT
            colour = TOPOLOGY_COLOURS.get(mission.topology, Rgba(0.5, 0.5, 0.5, 1.0))
            if len(xy) > 1:
                meshcat.SetLine(f"{path}/mission_{i}/line", np.vstack([xy.T, z]), 4.0, colour)
            target = f"{path}/mission_{i}/target"
            meshcat.SetObject(target, Sphere(0.06), colour)
            meshcat.SetTransform(target, RigidTransform([xy[-1, 0], xy[-1, 1], z[-1]]))
        # Hidden before it was planned, shown from now on (in a recording: over time).
        if t > 0:
            meshcat.SetProperty(path, "visible", False, 0.0)
        meshcat.SetProperty(path, "visible", True, t)
        self._drawn = key
        self.count += 1


def add_guidance_visualizer(builder, guidance_port, meshcat, heightmap) -> GuidancePathVisualizer:
    """Adds a GuidancePathVisualizer fed by ``guidance_port``; returns it."""
    system = builder.AddSystem(GuidancePathVisualizer(meshcat=meshcat, heightmap=heightmap))
    system.set_name("guidance_path_visualizer")
    builder.Connect(guidance_port, system.get_input_port())
    return system


__all__ = ["GuidancePathVisualizer", "add_guidance_visualizer", "mission_polyline"]
