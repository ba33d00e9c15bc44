"""Dynamic alternating tripod trotting (paper 002, Fig. 10) on the simulated Qingzhui."""

import numpy as np
import pytest

from qz_drake.classification.runs import simulate_trot, trot_scenario
from qz_drake.errors import ConfigError, TerrainError
from qz_drake.robot.params import TRIPOD_A, TRIPOD_B
from qz_drake.state_layout import tilt_deg
from qz_drake.systems.trotting import LDS, LTS, THS, WAS, TrotConfig, TrottingController


def _check_trot(run, speed, cycles=2):
    assert not run.fell
    T = 2 * TrotConfig().phase_duration
    late = run.times >= run.times[-1] - cycles * T
    t, x = run.times[late], run.states[late]
    mean_speed = (x[-1, 4] - x[0, 4]) / (t[-1] - t[0])
    assert mean_speed == pytest.approx(speed, abs=0.07)
    assert abs(run.states[-1, 5]) < 0.05  # no sideways drift
    assert max(tilt_deg(s) for s in run.states) < 5.0
    # Height held within 3 cm of the nominal 0.55 m.
    assert np.all(np.abs(run.states[run.times > 0.5, 6] - 0.55) < 0.03)
    gait = run.gait_state
    # Every leg cycles through all four states, and the tripods alternate: the legs of one
    # tripod are never all in the air together with a leg of the other.
    for leg in range(6):
        assert set(np.unique(gait[:, leg]).astype(int)) == {LDS, WAS, THS, LTS}
    for k in range(len(gait)):
        a_air = np.all(gait[k, list(TRIPOD_A)] == LDS)
        b_air = np.any(gait[k, list(TRIPOD_B)] == LDS)
        assert not (a_air and b_air)


def test_trots_at_0_3_m_per_s_on_flat_concrete():
    run = simulate_trot(trot_scenario("concrete", distance=2.0), duration=3.5, speed=0.3)
    _check_trot(run, 0.3)
    # Each finished stance gave a feature vector; none was too short.
    assert len(run.stance_leg) >= 6 * 3 and run.skipped_stances.sum() == 0


def test_trots_at_0_6_m_per_s_on_foam():
    run = simulate_trot(trot_scenario("foam", distance=3.0), duration=4.0, speed=0.6)
    _check_trot(run, 0.6)


def test_swing_reference_reaches_the_foothold_and_keeps_reaching_down():
    trot = TrottingController()
    c = trot.config
    lift, land = np.array([0.7, 0.0, -0.52]), np.array([0.85, 0.02, -0.52])
    p0, _ = trot._swing_reference(0.0, lift, land, -0.52)
    p_mid, _ = trot._swing_reference(c.touchdown_fraction / 2, lift, land, -0.52)
    p_td, v_td = trot._swing_reference(c.touchdown_fraction, lift, land, -0.52)
    p_late, _ = trot._swing_reference(1.5, lift, land, -0.52)
    np.testing.assert_allclose(p0, lift)
    np.testing.assert_allclose(p_td, land, atol=1e-12)
    assert p_mid[2] == pytest.approx(-0.52 + c.step_height)
    np.testing.assert_allclose(v_td[:2], 0.0, atol=1e-12)
    assert p_late[2] == pytest.approx(-0.52 - c.reach_depth)
    # The analytic velocity is the derivative of the position (per unit swing fraction).
    s, h = 0.3, 1e-6
    p1, v = trot._swing_reference(s, lift, land, -0.52)
    p2, _ = trot._swing_reference(s + h, lift, land, -0.52)
    np.testing.assert_allclose((p2 - p1) / h, v, atol=1e-4)


def test_bad_gait_and_material_values_name_the_field():
    with pytest.raises(ConfigError, match="trot.phase_duration"):
        TrotConfig(phase_duration=-0.1).check()
    with pytest.raises(ConfigError, match="trot.min_landing_fraction"):
        TrotConfig(min_landing_fraction=0.95).check()
    with pytest.raises(TerrainError, match="'gravel'"):
        trot_scenario("gravel")
    with pytest.raises(ConfigError, match="speed"):
        simulate_trot(trot_scenario("wood"), duration=1.0, speed=2.0)
