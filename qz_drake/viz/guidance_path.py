"""CapPlanner's guidance path in meshcat (paper 000 Fig. 6-8, issue 14): the missions the TLC
planned, drawn over the terrain and replaced at every replan, also in recordings.

Each guidance (the list of GuidedMissions the CapabilityVIPlanner outputs) is drawn once, when
it changes, as one band per mission through the cells its actions cross, a little above the
ground and coloured by the mission's topology, with a marker at the mission's target. In a
recording, guidance k is visible from the time it was planned until the next replan: a replay
shows the plan the robot was following at each moment.

The band is a flat ribbon of triangles PATH_WIDTH wide: meshcat draws lines one pixel wide
whatever width they are given, too thin to follow on a 20 m world (issue 39).
"""

from __future__ import annotations

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.geometry import Rgba, Sphere
from pydrake.math import RigidTransform
from pydrake.systems.framework import LeafSystem

# One colour per topology (paper 000's six), saturated so that each stands out from the
# terrain's greens and sands; unknown names are grey.
TOPOLOGY_COLOURS = {
    "nominal": Rgba(0.95, 0.05, 0.2, 1.0),
    "hind_bend": Rgba(0.1, 0.3, 1.0, 1.0),
    "front_bend": Rgba(0.0, 0.85, 0.25, 1.0),
    "hind_1_bend": Rgba(0.65, 0.1, 0.95, 1.0),
    "front_1_bend": Rgba(1.0, 0.6, 0.0, 1.0),
    "split_up": Rgba(0.0, 0.85, 0.9, 1.0),
}
# Height of the drawn path above the terrain. [m]
LIFT = 0.05
# Width of the drawn path and radius of the marker at a mission's target. [m]
PATH_WIDTH = 0.15
TARGET_RADIUS = 0.12
ROOT = "/capplanner/guidance"


def ribbon(points: np.ndarray, width: float = PATH_WIDTH) -> tuple[np.ndarray, np.ndarray]:
    """A flat band ``width`` wide along a polyline: (vertices (3, 2N), faces (3, 2N-2)). Points
    are (N, 3) x, y, z, no two consecutive ones alike; the band's edges lie width/2 to either
    side in the horizontal plane, across the mean of the directions of the segments that meet
    at each point."""
    points = np.asarray(points, dtype=float)
    segments = np.diff(points[:, :2], axis=0)
    segments /= np.linalg.norm(segments, axis=1, keepdims=True)
    along = np.vstack([segments[:1], segments[:-1] + segments[1:], segments[-1:]])
    along /= np.maximum(np.linalg.norm(along, axis=1, keepdims=True), 1e-12)
    across = np.column_stack([-along[:, 1], along[:, 0], np.zeros(len(points))]) * (width / 2)
    vertices = np.empty((2 * len(points), 3))
    vertices[0::2], vertices[1::2] = points + across, points - across
    left = 2 * np.arange(len(points) - 1)
    faces = np.vstack([np.column_stack([left, left + 1, left + 2]),
                       np.column_stack([left + 1, left + 3, left + 2])])
    return vertices.T, faces.T.astype(np.int32)


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
            xy = mission.polyline()
            z = np.asarray(self._heightmap.height(xy[:, 0], xy[:, 1]), dtype=float) + LIFT
            colour = TOPOLOGY_COLOURS.get(mission.topology, Rgba(0.5, 0.5, 0.5, 1.0))
            if len(xy) > 1:
                vertices, faces = ribbon(np.column_stack([xy, z]))
                # Double-sided (meshcat's default): seen from below on a slope, it still shows.
                meshcat.SetTriangleMesh(f"{path}/mission_{i}/path", vertices, faces, colour)
            target = f"{path}/mission_{i}/target"
            meshcat.SetObject(target, Sphere(TARGET_RADIUS), colour)
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


__all__ = ["GuidancePathVisualizer", "add_guidance_visualizer", "ribbon"]
