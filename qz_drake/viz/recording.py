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
"""

from __future__ import annotations

import base64
import json
import logging
import re
from pathlib import Path

_PAYLOAD = re.compile(rb'data:application/octet-binary;base64,([A-Za-z0-9+/=]+)')

# The scene path of Qingzhui's base body under Drake's MeshcatVisualizer.
ROBOT_BASE_PATH = "/drake/visualizer/qingzhui/base"
# Camera offset from the robot's base at the start: behind, to the right, above. [m]
CAMERA_OFFSET = (-2.6, -2.6, 1.8)
# Frames a second of the walks' recordings and how often the visualizer publishes for them
# (Drake's default is 64): a walking gait of 1-2 s cycles reads smoothly at 32, and the demo's
# 150 s walk was a 46 MB page at 64.
RECORDING_FPS = 32.0

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


def save_recording(meshcat, path: str | Path, *, follow_robot: bool = False,
                   follow_path: str = ROBOT_BASE_PATH) -> Path:
    """Publishes the meshcat recording and writes the static HTML.

    Args:
        follow_robot: the page's camera starts at CAMERA_OFFSET from the scene object
            ``follow_path`` (Qingzhui's base), looking at it, and follows it while the
            animation plays.
    """
    meshcat.PublishRecording()
    html = meshcat.StaticHtml()
    if follow_robot:
        script = _FOLLOW_SCRIPT % {"path": json.dumps([p for p in follow_path.split("/") if p]),
                                   "offset": json.dumps(list(CAMERA_OFFSET))}
        html = html.replace("</body>", script + "</body>", 1) if "</body>" in html else html + script
    path = Path(path)
    path.write_text(html)
    return path


_SEEK_SCRIPT = """<script>
window.addEventListener("load", function () {
  setTimeout(function () {
    viewer.animator.pause();
    viewer.animator.seek(%(time)r);
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
            "follows_robot": b"viewer.render_callback" in data}
