"""``qz blc``: one JSON object, exit 0/1/2, and a saved solution that holds its promises."""

import json

import numpy as np

from qz_drake.cli import main


def test_blc_flat_solve_writes_a_consistent_npz(tmp_path, capsys):
    out = tmp_path / "sol.npz"
    code = main(["blc", "--terrain", "flat", "--distance", "1.0", "--duration", "2.0", "--out", str(out), "--json"])
    result = json.loads(capsys.readouterr().out)
    assert code == 0 and result["success"], result
    for key in ("status", "solve_time_s", "iterations", "max_violation", "n_vars", "n_constraints",
                "dense"):
        assert key in result
    assert result["dense"]["passed"] and result["dense"]["min_swing_clearance"] > -2e-3
    data = np.load(out)
    assert float(data["foot_radius"]) > 0 and data["phase_durations"].shape[0] == 6
    t, pos, feet, force, contact = data["t"], data["base_pos"], data["foot_pos"], data["foot_force"], data["contact"]
    assert feet.shape == (len(t), 6, 3) and contact.shape == (len(t), 6)
    # Goal reached; stance feet carry the weight (vertical forces sum to m g on average).
    assert abs(pos[-1, 0] - pos[0, 0] - 1.0) < 1e-3
    mean_fz = np.mean(force[:, :, 2].sum(axis=1))
    assert abs(mean_fz - float(data["mass"]) * 9.81) < 0.05 * float(data["mass"]) * 9.81
    # Swing feet carry no force; stance feet stay inside the friction pyramid.
    assert np.all(np.abs(force[~contact]) < 1e-6)
    mu = float(data["mu"])
    fz = force[..., 2][contact]
    assert np.all(np.abs(force[..., 0][contact]) <= mu * fz + 1e-6)
    assert np.all(np.abs(force[..., 1][contact]) <= mu * fz + 1e-6)


def test_blc_bad_input_exits_2_with_one_line(capsys):
    assert main(["blc", "--distance", "-1", "--duration", "2"]) == 2
    err = capsys.readouterr().err
    assert "--distance = -1.0" in err and len(err.strip().splitlines()) == 1
    assert main(["blc", "--terrain", "lava", "--distance", "1", "--duration", "2"]) == 2
    assert "terrain.kind" in capsys.readouterr().err


def test_impossible_task_is_a_failed_result(capsys):
    code = main(["blc", "--distance", "5.0", "--duration", "1.0", "--json"])
    result = json.loads(capsys.readouterr().out)
    assert code == 1 and not result["success"] and result["reason"]


def test_blc_params_from_the_command_line(capsys):
    """--blc-param sets BlcParameters fields (free durations, the stance guess); a misspelt
    field or a value of the wrong type is one line naming it, exit 2."""
    code = main(["blc", "--distance", "1.0", "--duration", "2.0", "--json",
                 "--blc-param", "optimize_phase_durations=true", "--blc-param", "foothold_guess=stance",
                 "--blc-param", "phase_duration_bounds=[0.6, 1.8]"])
    result = json.loads(capsys.readouterr().out)
    assert code == 0 and result["success"], result
    swings = [d for leg in result["phase_durations"] for d in leg[1:-1:2]]
    nominal = 1.6 / 5  # five 0.32 s swing slots between the 0.2 s stands
    assert all(0.6 * nominal - 1e-6 <= d <= 1.8 * nominal + 1e-6 for d in swings)
    assert max(abs(d - nominal) for d in swings) > 1e-3  # optimised, not the nominal ones
    for bad, field in ((["optimise_phase_durations=true"], "--blc-param = 'optimise_phase_durations'"),
                       (["time_limit=soon"], "--blc-param time_limit"),
                       (["optimize_phase_durations=3"], "--blc-param optimize_phase_durations"),
                       (["foothold_guess=guess"], "blc.foothold_guess")):
        args = ["blc", "--distance", "1", "--duration", "2"]
        for item in bad:
            args += ["--blc-param", item]
        assert main(args) == 2
        err = capsys.readouterr().err
        assert field in err and len(err.strip().splitlines()) == 1, err
