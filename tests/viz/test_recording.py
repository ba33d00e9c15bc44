"""What a recording shows (issue 39): the whole scene lit, the terrain coloured by height with
every step apart from its neighbour, Qingzhui in colours of its own, and the simulated time."""

import base64
import re
import shutil
import struct
import subprocess

import numpy as np
import pytest
from pydrake.geometry import MeshcatVisualizer, MeshcatVisualizerParams, Role
from pydrake.multibody.plant import AddMultibodyPlantSceneGraph
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder

from qz_drake.robot.model import add_qingzhui
from qz_drake.robot.params import LEG_NAMES
from qz_drake.terrain import make_terrain
from qz_drake.terrain.drake_geometry import (BAND_SHADE, HEIGHT_BAND, add_heightmap_to_plant, heightmap_surface_obj,
                                             terrain_rgba)
from qz_drake.viz.recording import (AMBIENT_INTENSITY, ROBOT_COLOURS, ROBOT_PATH, recording_at, recording_meshcat,
                                    recording_summary, save_recording)

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser") or shutil.which("google-chrome")
DURATION = 0.5  # [s]


def _msgpack_double(value: float) -> bytes:
    return b"\xcb" + struct.pack(">d", value)


def _properties(html: bytes) -> dict[str, list[bytes]]:
    """The set_property commands of a saved page, by path."""
    found: dict[str, list[bytes]] = {}
    for match in re.finditer(rb"data:application/octet-binary;base64,([A-Za-z0-9+/=]+)", html):
        payload = base64.b64decode(match.group(1))
        if b"set_property" in payload[:64]:
            path = re.search(rb"(/[^\x00-\x1f\x7f-\xff]+)", payload).group(1).decode()
            found.setdefault(path, []).append(payload)
    return found


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    """Qingzhui dropped onto the stairs terrain for DURATION, recorded and saved."""
    builder = DiagramBuilder()
    plant, scene_graph = AddMultibodyPlantSceneGraph(builder, 0.002)
    add_heightmap_to_plant(plant, make_terrain("stairs"))
    add_qingzhui(plant)
    plant.Finalize()
    meshcat = recording_meshcat()
    MeshcatVisualizer.AddToBuilder(builder, scene_graph, meshcat, MeshcatVisualizerParams(role=Role.kIllustration))
    simulator = Simulator(builder.Build())
    meshcat.StartRecording(frames_per_second=32.0)
    simulator.AdvanceTo(DURATION)
    meshcat.StopRecording()
    return save_recording(meshcat, tmp_path_factory.mktemp("recording") / "recording.html", follow_robot=True)


def test_recording_lights_the_whole_scene(recording):
    properties = _properties(recording.read_bytes())
    # Meshcat's point lights (which fade out 10 m from the origin) off, the grid at z = 0 hidden.
    for path in ("/Lights/PointLightNegativeX", "/Lights/PointLightPositiveX", "/Grid"):
        assert any(b"visible" in p and p.endswith(b"\xc2") for p in properties[path]), path
    assert any(_msgpack_double(AMBIENT_INTENSITY) in p for p in properties["/Lights/AmbientLight/<object>"])
    assert {b"top_color", b"bottom_color"} <= {name for p in properties["/Background/<object>"]
                                               for name in re.findall(rb"(top_color|bottom_color)", p)}


def test_robot_has_its_colours_on_every_body(recording):
    properties = _properties(recording.read_bytes())
    bodies = {"base": "Box", **{f"{leg}_{part}": shape for leg in LEG_NAMES
                                for part, shape in (("hip", "Sphere"), ("thigh", "Cylinder"),
                                                    ("shank", "Cylinder"), ("foot", "Sphere"))}}
    for body, shape in bodies.items():
        colour = ROBOT_COLOURS["base" if body == "base" else body[body.index("_"):]]
        commands = properties.get(f"{ROBOT_PATH}/{body}/qingzhui/{shape}", [])
        assert any(b"color" in p and all(_msgpack_double(c) in p for c in colour) for p in commands), body


def test_page_shows_the_time_and_still_holds_the_walk(recording):
    summary = recording_summary(recording)
    assert summary["has_animation"] and summary["follows_robot"] and summary["shows_time"]


@pytest.mark.skipif(CHROMIUM is None, reason="needs chromium (apt-get install -y chromium) to render recordings")
def test_clock_reads_the_time_the_page_is_paused_at(recording, tmp_path):
    page = recording_at(recording, 0.25, tmp_path / "at.html", delay_ms=500)
    dom = subprocess.run([CHROMIUM, "--headless", "--no-sandbox", "--disable-gpu", "--use-gl=swiftshader",
                          "--enable-unsafe-swiftshader", "--virtual-time-budget=3000", "--dump-dom", page.as_uri()],
                         capture_output=True, text=True, timeout=240).stdout
    clock = re.search(r'id="qz-clock"[^>]*>([^<]*)<', dom)
    assert clock, dom[-2000:]
    assert clock.group(1) == f"t = 0.25 s / {DURATION:.2f} s"


def test_every_step_of_a_stair_differs_from_its_neighbours():
    # On a map 1.5 m high (the long_range world), steps of 0.1 m: the height ramp alone moves a
    # few per cent a step; the alternating bands keep neighbours apart.
    heights = np.arange(0.0, 1.0, HEIGHT_BAND)
    colours = np.array([terrain_rgba(h, -0.5, 1.0) for h in heights])
    step_change = np.abs(np.diff(colours[:, :3], axis=0)).max(axis=1)
    assert step_change.min() > 0.08
    assert np.all(colours[:, 3] == 1.0) and np.all(colours[:, :3] <= 1.0)
    # Low ground darker than high ground, whichever band.
    assert terrain_rgba(-0.5, -0.5, 1.0)[:3].sum() < BAND_SHADE * terrain_rgba(1.0, -0.5, 1.0)[:3].sum()
    # A map with material labels keeps its materials' colours (the same material at one height).
    np.testing.assert_array_equal(terrain_rgba(0.0, 0.0, 1.0, material="wood"),
                                  terrain_rgba(0.0, -3.0, 3.0, material="wood"))
    assert not np.allclose(terrain_rgba(0.0, 0.0, 1.0, material="wood"), terrain_rgba(0.0, 0.0, 1.0, material="foam"))


def test_mesh_terrain_is_drawn_in_height_bands_and_collides_as_one_mesh(tmp_path):
    plant, _ = AddMultibodyPlantSceneGraph(DiagramBuilder(), 0.001)
    heightmap = make_terrain("rough")
    assert add_heightmap_to_plant(plant, heightmap, contact="mesh", mesh_dir=tmp_path) == "mesh"
    # Contact is the whole surface, as before; only the drawing is split.
    assert plant.num_collision_geometries() == 1
    assert (tmp_path / "terrain_concrete.obj").read_text() == heightmap_surface_obj(heightmap)
    h = heightmap.heights
    quads = (h[:-1, :-1] + h[:-1, 1:] + h[1:, :-1] + h[1:, 1:]) / 4.0
    bands = np.unique(np.floor(np.round(quads / HEIGHT_BAND, 6)))
    assert len(bands) > 1 and len(plant.GetVisualGeometriesForBody(plant.world_body())) == len(bands)
    faces = sum(sum(line.startswith("f ") for line in path.read_text().splitlines())
                for path in tmp_path.glob("terrain_visual_concrete_*.obj"))
    assert faces == 2 * quads.size  # every quad drawn once
