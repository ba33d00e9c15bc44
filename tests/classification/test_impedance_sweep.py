"""Fig. 13 of paper 002: the one-leg impedance sweep reproduces the paper's ordering."""

import json

import numpy as np
import pytest

from qz_drake.classification.impedance_sweep import (ImpedanceSweepConfig, oscillation_amplitude, run_sweep,
                                                      simulate_leg)
from qz_drake.cli import main
from qz_drake.errors import ConfigError


def test_sweep_ordering_matches_the_paper(tmp_path, capsys):
    assert main(["impedance-sweep", "--json", "--out", str(tmp_path)]) == 0
    result = json.loads(capsys.readouterr().out)
    assert result["stiffness_N_per_m"] == [5000.0, 15000.0, 25000.0]
    soft, medium, hard = result["max_error_m"]
    # 15 kN/m tracks best; 5 kN/m sags about M g / K = 4 cm; 25 kN/m rings.
    assert medium < soft and medium < hard
    assert soft == pytest.approx(20.0 * 9.81 / 5e3, abs=0.01)
    assert result["oscillates"] == [False, False, True]
    assert (tmp_path / "impedance_sweep.png").stat().st_size > 10_000
    saved = json.loads((tmp_path / "impedance_sweep.json").read_text())
    assert saved["config"]["torque_lag"] == pytest.approx(0.012)


def test_without_drive_lag_a_stiff_leg_does_not_ring():
    # The ringing at 25 kN/m comes from the torque loop's lag, not from the contact model:
    # with an ideal drive the stiffest leg tracks best, a linear spring-mass answer.
    result = run_sweep(ImpedanceSweepConfig(stiffnesses=[25e3], torque_lag=0.0, duration=2.0))
    assert result["oscillates"] == [False]
    assert result["max_error_m"][0] < 0.015
    assert not result["lost_ground_contact"][0]


def test_static_balance_and_oscillation_measure():
    run = simulate_leg(15e3, ImpedanceSweepConfig(amplitude=0.0, duration=0.5, torque_lag=0.0))
    # Standing still, the leg sags M g / K, the ground (M + m) g / k_g, and the ground
    # carries the whole weight.
    np.testing.assert_allclose(run["error"], -20.0 * 9.81 / 15e3 - 21.16 * 9.81 / 70e3, atol=1e-5)
    np.testing.assert_allclose(run["ground_force"][-1], 21.16 * 9.81, rtol=1e-3)
    t = np.linspace(0, 2, 2001)
    slow = 0.01 * np.sin(2 * np.pi * t) + 0.002
    assert oscillation_amplitude(t, slow, 1.0) < 1e-9
    assert oscillation_amplitude(t, slow + 0.004 * np.sin(2 * np.pi * 6 * t), 1.0) == pytest.approx(0.004, rel=0.05)


def test_bad_input_names_the_field(capsys):
    with pytest.raises(ConfigError, match="stiffnesses"):
        run_sweep(ImpedanceSweepConfig(stiffnesses=[5e3, -1.0]))
    with pytest.raises(ConfigError, match="torque_lag"):
        simulate_leg(5e3, ImpedanceSweepConfig(torque_lag=float("nan")))
    assert main(["impedance-sweep", "--stiffness", "5,abc"]) == 2
    assert "--stiffness = '5,abc'" in capsys.readouterr().err
