"""Meshcat recordings as self-contained static HTML files.

``meshcat.StaticHtml()`` embeds every meshcat command as a base64 msgpack payload; the
animation of a recording is one ``set_animation`` command. ``recording_summary`` reads a saved
file back so tests and users can check that it really holds an animation.
"""

from __future__ import annotations

import base64
import re
from pathlib import Path

_PAYLOAD = re.compile(rb'data:application/octet-binary;base64,([A-Za-z0-9+/=]+)')


def save_recording(meshcat, path: str | Path) -> Path:
    """Publishes the meshcat recording and writes the static HTML."""
    meshcat.PublishRecording()
    path = Path(path)
    path.write_text(meshcat.StaticHtml())
    return path


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
            "has_animation": counts["set_animation"] > 0 and animation_bytes > 1000}
