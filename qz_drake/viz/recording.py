"""Meshcat recordings as self-contained static HTML files.

``meshcat.StaticHtml()`` embeds every meshcat command as a base64 msgpack payload; the
animation of a recording is one ``set_animation`` command. ``recording_summary`` reads a saved
file back so tests and users can check that it really holds an animation.

A batch run that only writes a recording still needs a Meshcat (Drake records through its
server): ``recording_meshcat`` makes one per process, on localhost only and without Drake's
"Meshcat listening" log line, and reuses it for every later recording. ``save_recording(...,
follow_robot=True)`` adds a few lines of script to the page that point the camera at the robot
and keep it there while the animation plays (the view follows the base body; the user can
still orbit and zoom).

A saved page's animation is stored compactly (``compact_animation``): a key frame is left out
where the motion between its neighbours is a straight line to within ANIMATION_TOLERANCE, and
each track's key frames are two float32 arrays, times and values, instead of meshcat's one map
per key frame of float64 numbers (three.js holds them as float32 arrays anyway). The demo's
110 s walk takes 1.7 MB of animation instead of 8.4 MB, and its page 6.3 MB instead of 26 MB
with the terrain drawn in merged planar patches (qz_drake.terrain.drake_geometry).

Recordings are lit evenly and coloured for reading at a glance (issue 39): ``style_recording``
replaces meshcat's default lights (point lights near the origin that left a 20 m world
near-black outside a spotlit patch) with an ambient light and one overhead directional light,
and draws Qingzhui's trunk orange and its legs blue over the terrain's greens and sands (the
terrain's colours are set where it is registered, qz_drake/terrain/drake_geometry.py). Every
saved page shows the animation's time in a corner of the view (``show_time``).
"""

from __future__ import annotations

import base64
import json
import logging
import re
from pathlib import Path

import numpy as np

from qz_drake.robot.params import LEG_NAMES

_PAYLOAD = re.compile(rb'data:application/octet-binary;base64,([A-Za-z0-9+/=]+)')

# The scene path of Qingzhui's base body under Drake's MeshcatVisualizer.
ROBOT_BASE_PATH = "/drake/visualizer/qingzhui/base"
# Camera offset from the robot's base at the start: behind, to the right, above. [m]
CAMERA_OFFSET = (-2.6, -2.6, 1.8)
# Frames a second of the walks' recordings and how often the visualizer publishes for them
# (Drake's default is 64): a walking gait of 1-2 s cycles reads smoothly at 32, and the demo's
# 150 s walk was a 46 MB page at 64.
RECORDING_FPS = 32.0
# Meshcat's msgpack extension type of a little-endian float32 array (its viewer decodes it to a
# Float32Array; meshcat-python writes numpy arrays so).
_MSGPACK_FLOAT32 = 0x17
# How far a body may be drawn from where it was recorded where compact_animation leaves key
# frames out, by track type: a position [m] and a unit quaternion's components (0.002: 0.23
# deg). A millimetre does not show on a 20 m world; it keeps 55 % of the demo's key frames
# (the contact's small vibrations are what needs the rest), 0.5 mm keeps 66 %.
ANIMATION_TOLERANCE = {"vector3": 1e-3, "quaternion": 2e-3}

# Lights of recordings, replacing meshcat's defaults. The ambient light carries most of the
# brightness so that every face, even one turned from the sun, reads; the directional light
# (meshcat's "FillLight", moved from the horizon to above the scene and brightened) comes from
# behind-left of the walking direction, so that treads, risers and the sides of boxes take three
# different shades. Meshcat's two point lights fade out 10 m from the origin: off.
AMBIENT_INTENSITY = 1.1
SUN_INTENSITY = 1.5
# Where the directional light shines from, in the world frame (towards the origin). [m]
SUN_POSITION = (-4.0, -6.0, 10.0)
# Sky gradient behind the scene (top, bottom), light enough that the terrain's edge shows.
BACKGROUND_TOP = (0.58, 0.72, 0.9)
BACKGROUND_BOTTOM = (0.9, 0.93, 0.96)
# Qingzhui's colours in recordings, by the suffix of a body's name: a saturated orange trunk and
# blue legs stand apart from the terrain's height ramp (greens to sands) and from each other.
# (The URDF's own colours are kept: models/qingzhui.urdf is part of the robot's fingerprint,
# which the shipped capability model is checked against.)
ROBOT_COLOURS = {
    "base": (1.0, 0.3, 0.0, 1.0),
    "_hip": (0.03, 0.08, 0.3, 1.0),
    "_thigh": (0.05, 0.2, 0.8, 1.0),
    "_shank": (0.15, 0.4, 1.0, 1.0),
    "_foot": (0.05, 0.05, 0.06, 1.0),
}
ROBOT_PATH = ROBOT_BASE_PATH.rpartition("/")[0]
# MeshcatVisualizer draws a body's unnamed URDF visual at BODY/MODEL/SHAPE, SHAPE its Drake type.
_DRAKE_SHAPES = ("Box", "Sphere", "Cylinder", "Capsule", "Ellipsoid", "Mesh", "Convex")

_meshcat = None

# Runs in the page after meshcat's viewer. Once the followed object is in the scene, the camera is
# put at CAMERA_OFFSET from it, looking at it; then, each frame, the camera and its target move by
# what the object moved since the last frame, so the view keeps the user's angle and zoom. The
# camera's parent frame is three.js's world frame (y up); Drake's world is the scene's frame.
_FOLLOW_SCRIPT = """<script>
(function () {
  var path = %(path)s, offset = %(offset)s, last = null;
  var previous = viewer.render_callback;
  viewer.render_callback = function () {
    previous();
    var node = viewer.scene_tree.find(path);
    var camera = viewer.camera, target = viewer.controls.target;
    if (!node.object || !camera.parent || Object.keys(node.children).length === 0) return;
    var p = target.clone();
    node.object.getWorldPosition(p);
    camera.parent.worldToLocal(p);
    if (last === null) {
      var o = p.clone().set(offset[0], offset[1], offset[2]).applyQuaternion(viewer.scene.quaternion);
      target.copy(p);
      camera.position.copy(p).add(o);
      camera.lookAt(target);
      viewer.set_dirty();
    } else {
      var d = p.clone().sub(last);
      if (d.lengthSq() > 0) { target.add(d); camera.position.add(d); viewer.set_dirty(); }
    }
    last = p;
  };
})();
</script>
"""


def recording_meshcat():
    """The process's Meshcat for recordings: created on first use, bound to localhost (no port
    on the network), with Drake's "Meshcat listening" INFO line kept out of the output."""
    global _meshcat
    if _meshcat is None:
        from pydrake.geometry import Meshcat, MeshcatParams

        logger = logging.getLogger("drake")
        level = logger.level
        logger.setLevel(max(logging.WARNING, level))
        try:
            _meshcat = Meshcat(MeshcatParams(host="localhost"))
        finally:
            logger.setLevel(level)
    else:
        _meshcat.Delete()
        _meshcat.DeleteRecording()
    return _meshcat


# The animation's time, bottom left over the view. It reads the animator's progress (what its
# time slider shows: kept at the end when the animation finishes, set by a seek in recording_at),
# so it needs nothing but the page itself.
_CLOCK_SCRIPT = """<div id="qz-clock" style="position: fixed; left: 12px; bottom: 12px; z-index: 10;
  padding: 4px 10px; border-radius: 4px; background: rgba(0, 0, 0, 0.6); color: #fff;
  font: 600 18px/1.3 monospace; pointer-events: none;">t = 0.00 s</div>
<script>
(function () {
  var clock = document.getElementById("qz-clock"), shown = null;
  function tick() {
    var animator = viewer.animator;
    var text = "t = " + animator.time.toFixed(2) + " s" +
      (animator.duration > 0 ? " / " + animator.duration.toFixed(2) + " s" : "");
    if (text !== shown) { clock.textContent = text; shown = text; }
    requestAnimationFrame(tick);
  }
  requestAnimationFrame(tick);
})();
</script>
"""


def style_recording(meshcat, *, robot_path: str = ROBOT_PATH) -> None:
    """Sets the lights, the background and (where ``robot_path`` is in the scene) Qingzhui's
    colours described at the top of this module. Properties set without a time hold for the
    whole recording."""
    meshcat.SetProperty("/Lights/PointLightNegativeX", "visible", False)
    meshcat.SetProperty("/Lights/PointLightPositiveX", "visible", False)
    meshcat.SetProperty("/Lights/AmbientLight/<object>", "intensity", AMBIENT_INTENSITY)
    meshcat.SetProperty("/Lights/FillLight/<object>", "intensity", SUN_INTENSITY)
    meshcat.SetProperty("/Lights/FillLight/<object>", "position", list(SUN_POSITION))
    # Meshcat's grid lies at z = 0, in the ground of every terrain, and streaks it.
    meshcat.SetProperty("/Grid", "visible", False)
    meshcat.SetProperty("/Background/<object>", "top_color", list(BACKGROUND_TOP))
    meshcat.SetProperty("/Background/<object>", "bottom_color", list(BACKGROUND_BOTTOM))
    model = robot_path.rpartition("/")[2]
    for part, colour in ROBOT_COLOURS.items():
        for body in [part] if part == "base" else [leg + part for leg in LEG_NAMES]:
            # On the geometry's own path: a saved page sets a body's properties before its
            # geometry exists, so a colour set on the body would find nothing to paint.
            for shape in _DRAKE_SHAPES:
                path = f"{robot_path}/{body}/{model}/{shape}"
                if meshcat.HasPath(path):
                    meshcat.SetProperty(path, "color", list(colour))


def thin_key_frames(times: np.ndarray, values: np.ndarray, tolerance: float) -> np.ndarray:
    """Indices of the key frames to keep, first and last among them, such that the linear
    interpolation between kept neighbours (what the viewer draws between key frames) is within
    ``tolerance`` of every value left out, in each component. ``times`` (N,), ``values`` (N, D).

    Kept frames start one every largest power of two; each span between kept frames whose
    interpolation misses a frame by more than the tolerance is halved, down to single frames."""
    count = len(times)
    if count < 3:
        return np.arange(count)
    step = 1 << int(np.log2(count - 1))
    kept = np.union1d(np.arange(0, count, step), [count - 1])
    index = np.arange(count)
    while True:
        span = np.minimum(np.searchsorted(kept, index, side="right") - 1, len(kept) - 2)
        start, end = kept[span], kept[span + 1]
        fraction = ((times - times[start]) / (times[end] - times[start]))[:, None]
        error = np.abs(values - values[start] - fraction * (values[end] - values[start])).max(axis=1)
        missed = np.zeros(len(kept), dtype=bool)
        missed[span[error > tolerance]] = True
        if not missed.any() or step == 1:
            return kept
        step //= 2
        candidates = np.arange(0, count, step)
        kept = np.union1d(kept, candidates[missed[span[candidates]]])


def _float32(values) -> "msgpack.ExtType":
    import msgpack

    return msgpack.ExtType(_MSGPACK_FLOAT32, np.asarray(values, dtype="<f4").tobytes())


def compact_animation(payload: bytes) -> bytes:
    """A ``set_animation`` command (msgpack) with the key frames of its position and rotation
    tracks thinned (thin_key_frames, ANIMATION_TOLERANCE) and stored as a float32 array of
    times and one of values, which three.js's ``KeyframeTrack.parse`` takes in place of a list of
    ``{time, value}`` maps; other tracks (a guidance path's visibility) are kept as they are, and
    any other command is returned as it is."""
    import msgpack

    command = msgpack.unpackb(payload, raw=False, strict_map_key=False)
    if not isinstance(command, dict) or command.get("type") != "set_animation":
        return payload
    for animation in command["animations"]:
        for track in animation["clip"]["tracks"]:
            keys = track.get("keys")
            if track.get("type") not in ANIMATION_TOLERANCE or not keys:
                continue
            times = np.array([key["time"] for key in keys], dtype=float)
            values = np.array([key["value"] for key in keys], dtype=float).reshape(len(keys), -1)
            kept = thin_key_frames(times, values, ANIMATION_TOLERANCE[track["type"]])
            track["times"], track["values"] = _float32(times[kept]), _float32(values[kept])
            del track["keys"]
    return msgpack.packb(command, use_bin_type=True)


def _compact_page(html: str) -> str:
    """The page with its animation command compacted (compact_animation)."""
    def compact(match):
        payload = base64.b64decode(match.group(1))
        if b"set_animation" not in payload[:64]:
            return match.group(0)
        return "data:application/octet-binary;base64," + base64.b64encode(compact_animation(payload)).decode()

    return re.sub(_PAYLOAD.pattern.decode(), compact, html)


def save_recording(meshcat, path: str | Path, *, follow_robot: bool = False,
                   follow_path: str = ROBOT_BASE_PATH, show_time: bool = True) -> Path:
    """Publishes the meshcat recording, lit and coloured by ``style_recording``, and writes the
    static HTML.

    Args:
        follow_robot: the page's camera starts at CAMERA_OFFSET from the scene object
            ``follow_path`` (Qingzhui's base), looking at it, and follows it while the
            animation plays.
        show_time: the page shows the animation's time (the simulated time) in a corner.
    """
    style_recording(meshcat)
    meshcat.PublishRecording()
    html = _compact_page(meshcat.StaticHtml())
    scripts = ""
    if follow_robot:
        scripts += _FOLLOW_SCRIPT % {"path": json.dumps([p for p in follow_path.split("/") if p]),
                                     "offset": json.dumps(list(CAMERA_OFFSET))}
    if show_time:
        scripts += _CLOCK_SCRIPT
    html = html.replace("</body>", scripts + "</body>", 1) if "</body>" in html else html + scripts
    path = Path(path)
    path.write_text(html)
    return path


_SEEK_SCRIPT = """<script>
window.addEventListener("load", function () {
  setTimeout(function () {
    viewer.animator.pause();
    viewer.animator.seek(%(time)r);
    viewer.animator.display_progress(%(time)r);
    viewer.render();
    viewer.render();
    var node = viewer.scene_tree.find(%(path)s);
    var p = viewer.controls.target.clone();
    node.object.getWorldPosition(p);
    p.project(viewer.camera);
    document.title = "qz-view " + JSON.stringify({time: %(time)r, ndc: [p.x, p.y, p.z]});
  }, %(delay_ms)d);
});
</script>
"""


def recording_at(path: str | Path, time: float, out: str | Path, *, follow_path: str = ROBOT_BASE_PATH,
                 delay_ms: int = 3000) -> Path:
    """A copy of a recording page that shows the animation paused at ``time`` [s] and writes
    where the followed object appears in its title: ``qz-view {"time": t, "ndc": [x, y, z]}``,
    normalised device coordinates (in view when x and y lie in [-1, 1]). For checks in a
    headless browser (tests/test_new_user.py): ``chromium --headless --dump-dom`` reads the
    title, ``--screenshot`` takes the picture."""
    html = Path(path).read_text()
    script = _SEEK_SCRIPT % {"time": float(time), "delay_ms": int(delay_ms),
                             "path": json.dumps([p for p in follow_path.split("/") if p])}
    out = Path(out)
    out.write_text(html.replace("</body>", script + "</body>", 1))
    return out


def recording_summary(path: str | Path) -> dict:
    """Counts the commands in a static HTML recording: objects, transforms and animations."""
    data = Path(path).read_bytes()
    counts = {"set_object": 0, "set_transform": 0, "set_property": 0, "set_animation": 0}
    animation_bytes = 0
    for match in _PAYLOAD.finditer(data):
        payload = base64.b64decode(match.group(1))
        head = payload[:64]
        for name in counts:
            if name.encode() in head:
                counts[name] += 1
                if name == "set_animation":
                    animation_bytes += len(payload)
                break
    return {"bytes": len(data), "commands": counts, "animation_bytes": animation_bytes,
            "has_animation": counts["set_animation"] > 0 and animation_bytes > 1000,
            "follows_robot": b"viewer.render_callback" in data,
            "shows_time": b'id="qz-clock"' in data}
