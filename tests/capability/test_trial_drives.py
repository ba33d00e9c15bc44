"""How trials drive the joints (TrialConfig.control_mode and time_step): the explicit Eq. 7 in
the controller at 2 ms (the datasets' setting) or Eq. 7's PD in the drives (the plant's
implicit PD on the tracker's q_des and v_des) at a longer step; a dataset is labelled by one."""

import random

import pytest

from qz_drake.capability.dataset import fingerprints
from qz_drake.capability.trials import TrialConfig, run_trial, trial_scenario, trial_specs
from qz_drake.errors import QzError

DRIVES = TrialConfig(control_mode="position", time_step=0.004)


@pytest.mark.parametrize("settings, field", [
    (dict(control_mode="servo"), "trials.control_mode"),
    (dict(time_step=0.004), "trials.time_step"),  # the explicit PD is unstable past 2 ms
    (dict(control_mode="position", time_step=0.02), "trials.time_step"),
    (dict(control_mode="position", time_step=0.0), "trials.time_step"),
])
def test_trial_drive_settings_are_checked_naming_the_field(settings, field):
    with pytest.raises(QzError, match=field):
        TrialConfig(**settings)


def test_a_trial_with_the_drives_pd_builds_its_scenario_and_walks_as_the_default_does():
    specs = trial_specs(11, 40)
    random.Random(2).shuffle(specs)
    spec = next(s for s in specs if s.trial_id == "11-581")  # a turn on the scene's start
    scenario, _ = trial_scenario(spec, DRIVES)
    assert scenario.station.control_mode == "position"
    assert (scenario.station.position_kp, scenario.station.position_kd) == (DRIVES.kp, DRIVES.kd)
    assert scenario.simulation.time_step == 0.004
    default, _ = trial_scenario(spec, TrialConfig())
    assert default.station.control_mode == "torque" and default.simulation.time_step == 0.002
    drives, explicit = run_trial(spec, DRIVES), run_trial(spec, TrialConfig())
    for record in (drives, explicit):
        assert record["status"] == "executed" and record["success"], record
        assert record["final_xy_error_m"] < 0.05 and record["max_joint_error_deg"] < 5.0
    # The labels of one setting are not the other's: the controller's fingerprint tells them apart.
    assert fingerprints(DRIVES)["controller"] != fingerprints(TrialConfig())["controller"]


def test_a_dataset_records_its_drive_setting_and_refuses_trials_driven_otherwise(tmp_path):
    """The setting is part of what labels a dataset: collected with the drives' PD, the folder
    says so, and a collection with the default joint PD into it is refused by name."""
    import json

    from qz_drake.capability.collect import collect
    from qz_drake.errors import ConfigError

    out = tmp_path / "drives"
    # Seed 0's first scene is a start no topology stands on: 18 invalid trials, no simulation.
    summary = collect(out, seed=0, scenes=1, workers=1, progress=False, config=DRIVES)
    assert summary.errors == 0
    settings = json.loads((out / "manifest.json").read_text())["settings"]
    assert (settings["control_mode"], settings["time_step"]) == ("position", 0.004)
    with pytest.raises(ConfigError, match="controller|control_mode"):
        collect(out, seed=0, scenes=1, workers=1, progress=False, config=TrialConfig())
