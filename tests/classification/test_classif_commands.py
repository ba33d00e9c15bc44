"""qz classify collect / train / experiment end to end on a small dataset, and bad input."""

import json

import numpy as np
import pytest

from qz_drake.cli import main


@pytest.mark.slow
def test_collect_train_experiment(tmp_path, capsys):
    out = tmp_path / "classify"
    assert main(["classify", "collect", "--out", str(out), "--materials", "concrete,foam", "--stances", "5",
                 "--run-duration", "4", "--mixed-runs", "1", "--json"]) == 0
    collected = json.loads(capsys.readouterr().out)
    assert collected["classes"] == ["concrete", "foam"]
    assert all(n == 5 for counts in collected["per_class_per_leg"].values() for n in counts.values())
    assert (out / "dataset.npz").is_file() and len(list((out / "runs").glob("*.npz"))) == 3
    # The mixed floor's concrete and foam stances join the dataset, its wood ones do not.
    assert collected["stances_from_mixed_floors"] > 0

    assert main(["classify", "train", "--dataset", str(out), "--out", str(out), "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["classes"] == ["concrete", "foam"]
    assert [leg["leg"] for leg in report["per_leg"]] == ["MF", "RF", "RB", "MB", "LB", "LF"]
    for leg in report["per_leg"]:
        assert np.sum(leg["confusion"]) == 2 and 0.0 <= leg["accuracy"] <= 1.0
        assert leg["C"] > 0 and leg["gamma"] > 0
    # Legs with enough mixed-floor stances report them apart (held-out 20 % of those).
    assert any("accuracy" in leg.get("mixed", {}) for leg in report["per_leg"])
    # Foam sinks 1 cm under a foot, concrete 0.5 mm: even five stances tell them apart.
    assert np.mean([leg["accuracy"] for leg in report["per_leg"]]) >= 0.75
    assert (out / "models.npz").is_file() and (out / "confusion.png").is_file()

    assert main(["classify", "experiment", "--models", str(out / "models.npz"), "--out", str(out / "exp"),
                 "--quick", "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    (case,) = result["vibration"]
    assert case["material"] == "foam" and not case["fixed"]["fell"] and not case["adaptive"]["fell"]
    assert case["fixed"]["final_stiffness_N_per_m"] == [9000.0] * 6
    # The adaptive legs confirmed foam and stiffened to 11 kN/m.
    assert case["adaptive"]["final_stiffness_N_per_m"].count(11000.0) >= 4
    assert set(result["mixed_floor"]["label_accuracy_per_leg"]) == {"MF", "RF", "RB", "MB", "LB", "LF"}
    for name in ("acceleration_boxplot", "height_boxplot", "label_timeline", "json"):
        assert (tmp_path / result["files"][name]).is_file()


def test_bad_input_is_one_line_exit_2(tmp_path, capsys):
    assert main(["classify", "collect", "--out", str(tmp_path), "--materials", "concrete,gravel"]) == 2
    assert "'gravel'" in capsys.readouterr().err
    assert main(["classify", "train", "--dataset", str(tmp_path / "none.npz")]) == 2
    assert "none.npz" in capsys.readouterr().err
    assert main(["classify", "experiment", "--models", str(tmp_path / "none.npz")]) == 2
    assert main(["classify", "collect", "--stances", "0", "--out", str(tmp_path)]) == 2
    assert "stances_per_class = 0" in capsys.readouterr().err
    assert main(["classify", "collect", "--workers", "0", "--out", str(tmp_path)]) == 2
    assert "workers = 0" in capsys.readouterr().err
    assert main(["classify", "stiffness-sweep", "--materials", "foam,gravel"]) == 2
    assert "'gravel'" in capsys.readouterr().err
    assert main(["classify", "stiffness-sweep", "--stiffness", "9000,-1"]) == 2
    assert "--stiffness" in capsys.readouterr().err
    assert main(["classify", "train", "--repeats", "0", "--dataset", str(tmp_path)]) == 2
    assert "--repeats = 0" in capsys.readouterr().err


@pytest.mark.slow
def test_stiffness_sweep_finds_the_softer_leg_quieter_on_foam(capsys):
    assert main(["classify", "stiffness-sweep", "--materials", "foam", "--stiffness", "5000,13000", "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    soft, stiff = result["table"]["foam"]
    assert not soft["fell"] and not stiff["fell"]
    # Measured: interquartile range 0.83 against 3.63 m/s^2 (benchmarks/BENCHMARKS.md).
    assert soft["vertical_acceleration_m_per_s2"]["iqr"] < 0.6 * stiff["vertical_acceleration_m_per_s2"]["iqr"]
    assert result["presets"] == {"foam": 5000.0}
