"""What a recording shows (issue 39): the whole scene lit, the terrain coloured by height with
every step apart from its neighbour, Qingzhui in colours of its own, and the simulated time; a
page rendered in headless Chromium shows them (Debian's chromium: .ci/run installs it); its
animation stored compactly."""

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
from qz_drake.viz.recording import (AMBIENT_INTENSITY, ANIMATION_TOLERANCE, ROBOT_COLOURS, ROBOT_PATH,
                                    compact_animation, recording_at, recording_meshcat, recording_summary,
                                    save_recording, thin_key_frames)

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser") or shutil.which("google-chrome")
CHROMIUM_FLAGS = ("--headless", "--no-sandbox", "--disable-gpu", "--use-gl=swiftshader", "--enable-unsafe-swiftshader")
NO_CHROMIUM = "needs chromium (apt-get install -y chromium; .ci/run installs it) to render recordings"
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


@pytest.mark.skipif(CHROMIUM is None, reason=NO_CHROMIUM)
def test_clock_reads_the_time_the_page_is_paused_at(recording, tmp_path):
    page = recording_at(recording, 0.25, tmp_path / "at.html", delay_ms=500)
    dom = subprocess.run([CHROMIUM, *CHROMIUM_FLAGS, "--virtual-time-budget=3000", "--dump-dom", page.as_uri()],
                         capture_output=True, text=True, timeout=240).stdout
    clock = re.search(r'id="qz-clock"[^>]*>([^<]*)<', dom)
    assert clock, dom[-2000:]
    assert clock.group(1) == f"t = 0.25 s / {DURATION:.2f} s"


@pytest.mark.skipif(CHROMIUM is None, reason=NO_CHROMIUM)
def test_the_rendered_page_shows_the_robot_on_the_terrain_in_daylight(recording, tmp_path):
    from PIL import Image

    page = recording_at(recording, 0.25, tmp_path / "at.html", delay_ms=500)
    shot = tmp_path / "shot.png"
    subprocess.run([CHROMIUM, *CHROMIUM_FLAGS, "--virtual-time-budget=3000", "--window-size=800,600",
                    f"--screenshot={shot}", page.as_uri()], capture_output=True, timeout=240)
    image = np.asarray(Image.open(shot).convert("RGB"), dtype=float)
    assert image.shape == (600, 800, 3)
    # Neither a blank page nor a dark scene (a black canvas, meshcat's lights near the origin).
    assert 60 < image.mean() < 240 and image.std() > 20, (image.mean(), image.std())
    red, green, blue = image[..., 0], image[..., 1], image[..., 2]
    share = {"orange trunk": np.mean((red > green + 50) & (green > blue + 40)),
             "blue legs": np.mean((red < 90) & (blue > red + 90)),
             "green terrain": np.mean((green > red + 20) & (green > blue + 10))}
    assert share["orange trunk"] > 0.003 and share["blue legs"] > 0.0005 and share["green terrain"] > 0.05, share


def test_key_frames_are_left_out_only_where_the_motion_is_a_straight_line():
    times = np.arange(33.0)
    # A straight line needs its ends; a corner needs the corner too.
    assert thin_key_frames(times, np.column_stack([times, 2 * times]), 1e-3).tolist() == [0, 32]
    corner = np.abs(times - 10.0)[:, None]
    assert thin_key_frames(times, corner, 1e-3).tolist() == [0, 8, 10, 12, 16, 32]
    # Anything else: what the viewer draws between the frames kept is within the tolerance.
    rng = np.random.default_rng(0)
    walk = np.cumsum(rng.normal(0.0, 1e-3, (500, 3)), axis=0)
    kept = thin_key_frames(np.arange(500.0), walk, 2e-3)
    assert 2 < len(kept) < 500 and kept[0] == 0 and kept[-1] == 499
    drawn = np.column_stack([np.interp(np.arange(500.0), kept, walk[kept, k]) for k in range(3)])
    assert np.abs(drawn - walk).max() <= 2e-3


def test_the_saved_animation_holds_float32_arrays_within_the_tolerance(recording):
    import msgpack

    from qz_drake.viz.recording import _PAYLOAD

    payload = next(base64.b64decode(m.group(1)) for m in _PAYLOAD.finditer(recording.read_bytes())
                   if b"set_animation" in base64.b64decode(m.group(1))[:64])
    tracks = [track for animation in msgpack.unpackb(payload, raw=False)["animations"]
              for track in animation["clip"]["tracks"]]
    assert tracks and all("keys" not in t for t in tracks if t["type"] in ANIMATION_TOLERANCE)
    for track in tracks:
        times = np.frombuffer(track["times"].data, dtype="<f4")
        values = np.frombuffer(track["values"].data, dtype="<f4").reshape(len(times), -1)
        assert track["times"].code == track["values"].code == 0x17  # meshcat's Float32Array
        assert values.shape[1] == {"vector3": 3, "quaternion": 4}[track["type"]]
        assert np.all(np.diff(times) > 0) and times[-1] == pytest.approx(DURATION * 32.0, abs=1.0)
    # Another command passes unchanged.
    other = msgpack.packb({"type": "set_property", "path": "/Grid", "property": "visible", "value": False})
    assert compact_animation(other) == other


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
    area = 0.0
    for path in tmp_path.glob("terrain_visual_concrete_*.obj"):
        lines = path.read_text().splitlines()
        vertices = np.array([line.split()[1:3] for line in lines if line.startswith("v ")], dtype=float)
        a, b, c = (vertices[np.array([int(line.split()[k]) for line in lines if line.startswith("f ")]) - 1]
                   for k in (1, 2, 3))
        area += 0.5 * np.sum((b - a)[:, 0] * (c - a)[:, 1] - (b - a)[:, 1] * (c - a)[:, 0])
    assert area == pytest.approx(quads.size * heightmap.resolution ** 2)  # every quad drawn once
