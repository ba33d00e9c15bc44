"""How trials drive the joints (TrialConfig.control_mode and time_step): Eq. 7's PD in the
drives (the plant's implicit PD on the tracker's q_des and v_des) at the walks' step (the
default, config.WalkDrives) or the explicit Eq. 7 in the controller at 2 ms (every dataset
before issue 53's defaults); a dataset is labelled by one."""

import random

import pytest

from qz_drake.capability.dataset import fingerprints
from qz_drake.capability.trials import TrialConfig, run_trial, stored_trial_config, trial_scenario, trial_specs
from qz_drake.errors import QzError

DRIVES = TrialConfig(control_mode="position", time_step=0.004)
EXPLICIT = TrialConfig(control_mode="torque", time_step=0.002)


@pytest.mark.parametrize("settings, field", [
    (dict(control_mode="servo"), "trials.control_mode"),
    (dict(control_mode="torque", time_step=0.004), "trials.time_step"),  # the explicit PD is unstable past 2 ms
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
    assert default.station.control_mode == "position" and default.simulation.time_step == 0.008
    assert (default.station.position_kp, default.station.position_kd) == (1500.0, 30.0)
    explicit_scenario, _ = trial_scenario(spec, EXPLICIT)
    assert explicit_scenario.station.control_mode == "torque" and explicit_scenario.simulation.time_step == 0.002
    records = run_trial(spec, DRIVES), run_trial(spec, TrialConfig()), run_trial(spec, EXPLICIT)
    for record in records:
        assert record["status"] == "executed" and record["success"], record
        assert record["final_xy_error_m"] < 0.05 and record["max_joint_error_deg"] < 5.0
    # The labels of one setting are not the other's: the controller's fingerprint tells them apart.
    assert fingerprints(DRIVES)["controller"] != fingerprints(TrialConfig())["controller"]
    assert fingerprints(EXPLICIT)["controller"] != fingerprints(TrialConfig())["controller"]


def test_a_dataset_from_before_the_drive_fields_reads_as_it_was_labelled():
    # Every dataset collected before the fields existed drove the joints by the controller's PD at
    # 2 ms: its manifest's settings are read so, not with today's defaults.
    assert stored_trial_config({"kp": 1500.0, "blc_max_iterations": 30}) == EXPLICIT
    assert stored_trial_config({"control_mode": "position", "time_step": 0.008}) == TrialConfig()
    with pytest.raises(QzError, match="dataset.settings"):
        stored_trial_config({"gain": 3.0})


def test_a_dataset_records_its_drive_setting_and_refuses_trials_driven_otherwise(tmp_path):
    """The setting is part of what labels a dataset: collected with the drives' PD, the folder
    says so, and a collection with the controller's joint PD into it is refused by name."""
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
        collect(out, seed=0, scenes=1, workers=1, progress=False, config=EXPLICIT)


def test_a_dataset_from_before_the_drive_fields_resumes_as_collected_and_refuses_the_new_defaults(tmp_path):
    """A manifest without the fields (the shipped datasets') is continued by a collection asking
    for the controller's PD at 2 ms, and refused by name for today's defaults."""
    import json

    from qz_drake.capability.collect import collect
    from qz_drake.errors import ConfigError

    out = tmp_path / "old"
    # Seed 0's first scene is a start no topology stands on: 18 invalid trials, no simulation.
    collect(out, seed=0, scenes=1, workers=1, progress=False, config=EXPLICIT)
    manifest = json.loads((out / "manifest.json").read_text())
    for key in ("control_mode", "time_step", "blc_ladder", "blc_terminal_stance"):
        del manifest["settings"][key]
    (out / "manifest.json").write_text(json.dumps(manifest))
    before = (out / "manifest.json").read_text()
    assert collect(out, seed=0, scenes=1, workers=1, progress=False, config=EXPLICIT).errors == 0
    assert (out / "manifest.json").read_text() == before  # nothing left to run, nothing written
    with pytest.raises(ConfigError, match="settings.control_mode = 'torque' in the dataset, 'position' now"):
        collect(out, seed=0, scenes=1, workers=1, progress=False, config=TrialConfig())
