"""The quadruped walks searched static gaits in Drake (paper 003 section 4): references, walks on
flat and cuboid terrain, a recording, and a walk that must fail."""

import numpy as np
import pytest
from pydrake.geometry import Meshcat

from qz_drake.errors import ConfigError
from qz_drake.planning.static_gait import LEGS, cuboid_terrain, search_gait
from qz_drake.planning.static_gait_sim import (StaticGaitSimConfig, _box_path, foot_centre_heights, gait_reference,
                                               simulate_static_gait)
from qz_drake.terrain import HeightMap
from qz_drake.viz.recording import recording_summary


def test_box_path_goes_up_across_down():
    start, end, top = np.array([0.0, 0.0, 0.01]), np.array([0.08, 0.0, 0.03]), 0.07
    s = np.linspace(0, 1, 401)
    p = _box_path(start, end, top, s)
    assert p[0] == pytest.approx(start) and p[-1] == pytest.approx(end)
    # Segments of 0.06, 0.08 and 0.04 m: the first 6/18 of the phase is the straight lift.
    lift = s <= 6 / 18
    assert np.allclose(p[lift, :2], start[:2]) and np.all(np.diff(p[lift, 2]) >= 0)
    across = (s >= 6 / 18) & (s <= 14 / 18)
    assert np.allclose(p[across, 2], top)
    assert p[:, 2].max() == pytest.approx(top)


def test_foot_rests_on_an_edge_it_overhangs():
    heights = np.zeros((20, 20))
    heights[:, 10:] = 0.02  # a 2 cm step up from x = 0.0475 (cell 10 starts half a cell early)
    terrain = HeightMap(heights, 0.005, (0.0, 0.0))
    r = 0.012
    # Far from the step: the centre is r above the ground; on top: r above the step.
    assert foot_centre_heights(terrain, [[0.01, 0.05]], r)[0] == pytest.approx(r)
    assert foot_centre_heights(terrain, [[0.08, 0.05]], r)[0] == pytest.approx(0.02 + r)
    # 5 mm before the step's edge at x = 0.0475: the sphere rests on the edge.
    assert foot_centre_heights(terrain, [[0.0425, 0.05]], r)[0] == pytest.approx(0.02 + np.sqrt(r**2 - 0.005**2))


@pytest.fixture(scope="module")
def flat_gait():
    terrain = cuboid_terrain(0, max_height=0.0)
    return terrain, search_gait(terrain, (0.0, 0.0), 0.0, steps=4, depth=2)


def test_reference_follows_the_states(flat_gait):
    terrain, result = flat_gait
    config = StaticGaitSimConfig()
    ref = gait_reference(terrain, result, config)
    assert ref.times[0] == 0 and np.all(np.diff(ref.times) > 0)
    for k, state in enumerate(result.states):
        shift, swing = ref.phase_starts[k]
        i = LEGS.index(state.leg)
        # At the end of the shift the body is at the state's pose, all feet where they stood.
        at = np.searchsorted(ref.times, swing)
        assert ref.p_WB[at] == pytest.approx(state.p_WB) and ref.rpy[at] == pytest.approx(state.rpy)
        during_shift = (ref.times >= shift) & (ref.times <= swing)
        assert np.ptp(ref.feet[during_shift], axis=0).max() < 1e-12
        # After the swing the foot centre is foot_radius above its foothold.
        end = np.searchsorted(ref.times, swing + config.swing_duration)
        assert ref.feet[end, i] == pytest.approx(state.feet[i] + [0, 0, 0.012])
        # Only the swing foot moves, and it rises swing_height over the ground.
        during_swing = (ref.times >= swing) & (ref.times <= swing + config.swing_duration)
        moving = np.ptp(ref.feet[during_swing], axis=0).max(axis=1) > 1e-9
        assert moving.tolist() == [j == i for j in range(4)]
        assert ref.feet[during_swing, i, 2].max() == pytest.approx(0.012 + result.config.swing_height)


def test_walks_four_steps_on_flat_ground_with_recording(flat_gait, tmp_path):
    terrain, result = flat_gait
    walk = simulate_static_gait(terrain, result, meshcat=Meshcat(), recording_path=tmp_path / "walk.html",
                                progress=True)
    m = walk.metrics
    assert m["success"], m["reason"]
    assert m["final_error_m"] < 0.02 and m["max_tilt_deg"] < 3.0 and not m["body_terrain_contact"]
    # Four steps of a crawl move the body one stride's worth forward along x.
    assert walk.p_WB[-1, 0] - walk.p_WB[0, 0] == pytest.approx(result.states[-1].p_WB[0], abs=0.02)
    assert recording_summary(walk.recording)["has_animation"]


def test_walks_four_steps_on_cuboids():
    terrain = cuboid_terrain(3, max_height=0.025)
    result = search_gait(terrain, (0.0, 0.0), 0.0, steps=4, depth=4)
    assert result.success
    walk = simulate_static_gait(terrain, result)
    m = walk.metrics
    assert m["success"], m["reason"]
    assert m["final_error_m"] < 0.02 and m["body_tracking_max_m"] < 0.02 and not m["body_terrain_contact"]
    # Feet stay on their footholds: every landed foot within a centimetre of its reference.
    landed = walk.feet[-1] - walk.reference.feet[-1]
    assert np.abs(landed).max() < 0.01


def test_gait_searched_on_other_terrain_fails():
    """A gait planned for flat ground, walked where a 12 cm block stands under the body."""
    flat = cuboid_terrain(0, max_height=0.0)
    result = search_gait(flat, (0.0, 0.0), 0.0, steps=4, depth=1)
    blocked = cuboid_terrain(0, max_height=0.0)
    blocked.heights[:, (blocked.x_coords > 0.02) & (blocked.x_coords < 0.07)] = 0.12
    walk = simulate_static_gait(blocked, result, StaticGaitSimConfig(hold_duration=0.1))
    assert not walk.metrics["success"]
    assert walk.metrics["body_terrain_contact"] or walk.metrics["fell"]


@pytest.mark.parametrize("field, value", [("kp", -1.0), ("time_step", 0.0), ("discrete_contact_approximation", "tamsi")])
def test_bad_config_names_the_field(flat_gait, field, value):
    terrain, result = flat_gait
    with pytest.raises(ConfigError, match=field):
        simulate_static_gait(terrain, result, StaticGaitSimConfig(**{field: value}))
