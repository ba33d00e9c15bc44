"""CapPlanner's guidance path in meshcat: drawn when the guidance changes, one band per mission
over the terrain, and in a recording each guidance visible only while it was the plan."""

import base64
import re

import numpy as np
import pytest
from pydrake.common.value import AbstractValue
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder, LeafSystem

from qz_drake.planning.capability_mdp import PathStep
from qz_drake.planning.guidance import GuidedMission
from qz_drake.terrain.generators import step
from qz_drake.viz.guidance_path import (LIFT, PATH_WIDTH, ROOT, add_guidance_visualizer,
                                        ribbon)
from qz_drake.viz.recording import recording_meshcat


def _mission(x, y, heading, moves, topology="nominal"):
    steps = []
    for motion in moves:
        steps.append(PathStep(x=x, y=y, heading=heading, topology=topology, action_topology=topology,
                              motion=motion, success=0.95))
        if motion == "forward":
            dx, dy = [(1, 0), (1, 1), (0, 1)][heading]
            x, y = x + dx, y + dy
        else:
            heading += 1
    return GuidedMission(target=(x, y, heading * np.pi / 4), topology=topology, steps=steps, success=0.9)


class _Replanner(LeafSystem):
    """Outputs the first guidance until t = 1 s, the second after (a replan)."""

    def __init__(self, first, second):
        super().__init__()
        self.DeclareAbstractOutputPort(
            "guidance", lambda: AbstractValue.Make([]),
            lambda context, out: out.set_value(first if context.get_time() < 1.0 else second))


def test_polyline_follows_the_cells_of_the_actions():
    m = _mission(0.0, 0.0, 0, ["forward", "forward", "turn_left", "forward"])
    np.testing.assert_allclose(m.polyline(), [[0, 0], [1, 0], [2, 0], [3, 1]])


def test_path_is_a_band_of_its_width_along_the_polyline():
    # Meshcat draws lines one pixel wide whatever their width: the path is a band of triangles.
    points = np.array([[0.0, 0.0, 0.05], [1.0, 0.0, 0.05], [2.0, 1.0, 0.25]])
    vertices, faces = ribbon(points, width=0.2)
    assert vertices.shape == (3, 6) and faces.shape == (3, 4) and faces.max() == 5
    # Straight ends: the edges lie 0.1 m to the left and right of the point, at its height.
    np.testing.assert_allclose(vertices[:, 0], [0.0, 0.1, 0.05], atol=1e-12)
    np.testing.assert_allclose(vertices[:, 1], [0.0, -0.1, 0.05], atol=1e-12)
    np.testing.assert_allclose(vertices[:, 5] - points[2], [0.1 / np.sqrt(2), -0.1 / np.sqrt(2), 0.0], atol=1e-12)
    # At the bend the edges lie across the mean direction, (1, 0) and (1, 1) / sqrt(2) averaged.
    across = vertices[:, 2] - vertices[:, 3]
    np.testing.assert_allclose(across @ [1 + 1 / np.sqrt(2), 1 / np.sqrt(2), 0.0], 0.0, atol=1e-12)
    assert np.linalg.norm(across) == pytest.approx(0.2)
    # Every triangle spans the band: two corners on one edge, one on the other.
    assert all(len(set(face % 2)) == 2 for face in faces.T)


def test_guidance_drawn_over_the_terrain_and_replaced_at_a_replan(tmp_path):
    heightmap = step(height=0.2, start_x=1.5)
    first = [_mission(0.0, 0.0, 0, ["forward", "forward"]),
             _mission(2.0, 0.0, 0, ["turn_left", "forward"], topology="front_bend")]
    second = [_mission(1.0, 0.0, 0, ["turn_left", "forward", "forward"], topology="split_up")]
    meshcat = recording_meshcat()
    builder = DiagramBuilder()
    source = builder.AddSystem(_Replanner(first, second))
    viz = add_guidance_visualizer(builder, source.get_output_port(), meshcat, heightmap)
    simulator = Simulator(builder.Build())
    meshcat.StartRecording()
    simulator.AdvanceTo(2.0)
    meshcat.StopRecording()
    assert viz.count == 2  # drawn once per guidance, not at every publish
    for path in (f"{ROOT}/0/mission_0/path", f"{ROOT}/0/mission_1/target", f"{ROOT}/1/mission_0/path"):
        assert meshcat.HasPath(path), path
    meshcat.PublishRecording()
    html = meshcat.StaticHtml().encode()
    payloads = [base64.b64decode(p) for p in
                re.findall(rb"data:application/octet-binary;base64,([A-Za-z0-9+/=]+)", html)]
    animation = [p for p in payloads if b"set_animation" in p[:64]]
    assert animation and b"guidance" in animation[0] and b"visible" in animation[0]
    # The first mission's band runs 5 cm above the ground, then above the 0.2 m step, its edges
    # PATH_WIDTH / 2 to either side of the cells' centres (y = 0).
    band = [p for p in payloads if b"0/mission_0/path" in p and b"set_object" in p[:64]][0]
    for value in (LIFT, 0.2 + LIFT, PATH_WIDTH / 2, -PATH_WIDTH / 2):
        assert np.float32(value).tobytes() in band, value
