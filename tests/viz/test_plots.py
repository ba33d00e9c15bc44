"""The walk's figures (qz_drake.viz.plots): the foot heights of a long walk stay readable."""

import numpy as np
from PIL import Image

from qz_drake.viz.plots import CONTACT_WINDOW, contact_window, plot_foot_heights


def _tripod_walk(duration: float, rate: float = 100.0):
    """Foot heights and contacts of a tripod gait of 0.4 s phases for ``duration`` [s]."""
    times = np.arange(0.0, duration, 1.0 / rate)
    swing = (np.floor(times / 0.4) % 2).astype(int)
    contacts = np.stack([swing != leg % 2 for leg in range(6)], axis=1).astype(float)
    lift = 0.12 * np.abs(np.sin(np.pi * times / 0.4))[:, None]
    return times, 0.03 + np.where(contacts > 0.5, 0.0, lift), contacts


def test_a_long_walk_shows_its_contact_phases_over_a_window_around_the_highest_foot(tmp_path):
    # Over a whole 110 s walk, a band per contact merged into solid green (the demo's plot).
    times, foot_z, contacts = _tripod_walk(110.0)
    foot_z[7000, 2] = 0.5  # a climb at 70 s
    first, last = contact_window(times, foot_z)
    assert last - first == CONTACT_WINDOW and first < 70.0 < last
    assert contact_window(times[:500], foot_z[:500]) == (0.0, times[499])  # a short walk: all of it
    image = np.asarray(Image.open(plot_foot_heights(times, foot_z, contacts, tmp_path / "feet.png")).convert("RGB"),
                       dtype=float)
    # Each contact is a green band of its own, tens of pixels wide (over the whole walk, 3).
    red, green, blue = image[..., 0], image[..., 1], image[..., 2]
    shaded = ((green > red + 20) & (green > blue + 20)).astype(int)
    edges = np.diff(np.pad(shaded, ((0, 0), (1, 1))), axis=1)
    widths = np.flatnonzero(edges.ravel() == -1) - np.flatnonzero(edges.ravel() == 1)
    assert np.median(widths) > 20, np.median(widths)
