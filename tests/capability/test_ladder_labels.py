"""Labels of the BLC the planners walk with (issue 54): the trials' BLC ladder.

A walk's BLC solves a refused mission again on the ladder's rungs before the planner hears of
the refusal; labels from the first solve alone would call "no plan" what the walk plans. With
``TrialConfig.blc_ladder`` every protocol (one-move trials, episodes, plan chains) labels with
the same ladder."""

import dataclasses

import pytest

from qz_drake.capability.episodes import EpisodeSpec, run_episode
from qz_drake.capability.plan_chains import run_plan_chain, solve_on_ladder
from qz_drake.capability.scenes import scene_recipe
from qz_drake.capability.trials import LADDER_ALLOWANCE, TrialConfig
from qz_drake.errors import QzError


class _Planner:
    """A planner that plans only on the rungs in ``plans_on``; counts its calls."""

    def __init__(self, plans_on, iterations=7):
        self.plans_on, self.iterations, self.calls = set(plans_on), iterations, []
        self.last_iterations = 0

    def __call__(self, start, target, topology, start_time, rung=""):
        self.calls.append(rung)
        self.last_iterations = self.iterations
        if rung in self.plans_on:
            return f"plan on {rung!r}", ""
        return None, f"BLC: refused on {rung!r}"


class _Start:
    time = 1.5


def test_a_refused_mission_is_solved_on_the_rungs_in_order_until_one_plans():
    planner = _Planner({"split"})
    plan, reason, iterations = solve_on_ladder(planner, ("cycles+1", "split", "cycles+2"), _Start(), (1, 0, 0), "nominal")
    assert plan == "plan on 'split'" and reason == ""
    assert planner.calls == ["", "cycles+1", "split"] and iterations == 21
    # No rung plans it: refused with the first solve's reason, every rung tried.
    planner = _Planner(set())
    plan, reason, iterations = solve_on_ladder(planner, ("cycles+1", "split"), _Start(), (1, 0, 0), "nominal")
    assert plan is None and reason == "BLC: refused on ''" and planner.calls == ["", "cycles+1", "split"]
    # A first solve that plans costs nothing more; no ladder is the first solve alone.
    planner = _Planner({""})
    assert solve_on_ladder(planner, ("cycles+1",), _Start(), (1, 0, 0), "nominal")[0] == "plan on ''"
    assert planner.calls == [""]
    planner = _Planner(set())
    assert solve_on_ladder(planner, (), _Start(), (1, 0, 0), "nominal")[2] == 7 and planner.calls == [""]


def test_the_trials_ladder_is_kept_in_one_form_and_bad_rungs_are_refused_by_name():
    assert TrialConfig(blc_ladder=" cycles+1, split ,free").blc_ladder == "cycles+1,split,free"
    assert TrialConfig().blc_ladder == "" and TrialConfig().ladder_allowance == 0.0
    assert TrialConfig(blc_ladder="split").ladder_allowance == LADDER_ALLOWANCE
    for bad in ("cycles", "split+9", "cycles+1,cycles+1", 3):
        with pytest.raises(QzError, match="trials.blc_ladder"):
            TrialConfig(blc_ladder=bad)


def _flat_spec(topology: str = "nominal") -> EpisodeSpec:
    scene = next(i for i in range(200) if scene_recipe(0, i)[0] == "flat")
    return EpisodeSpec(0, scene * 6, scene, topology)


def test_plan_chains_and_episodes_label_with_the_ladder():
    # One Ipopt iteration plans nothing, on any rung: each refused command's iterations count
    # the first solve and both rungs', and the refusal keeps the first solve's reason.
    config = dataclasses.replace(TrialConfig(blc_max_iterations=1), blc_ladder="cycles+1,cycles+2")
    moves = [r for r in run_plan_chain(_flat_spec(), config) if r["kind"] != "switch"]
    assert moves and not any(r["blc_success"] for r in moves)
    assert {r["blc_iterations"] for r in moves} == {3}
    assert {r["reason"] for r in moves} == {"blc_time_limit"}
    without = [r for r in run_plan_chain(_flat_spec(), TrialConfig(blc_max_iterations=1)) if r["kind"] != "switch"]
    assert {r["blc_iterations"] for r in without} == {1}
    # An episode's first mission, refused on every rung, is not walked: one record, three solves.
    records = run_episode(_flat_spec(), config)
    assert len(records) == 1 and records[0]["status"] == "executed" and not records[0]["blc_success"]
    assert records[0]["blc_iterations"] == 3 and records[0]["reason"] == "blc_time_limit"
    assert "no rung of the ladder planned it" in records[0]["blc_reason"]


def test_only_episodes_that_refused_or_failed_something_are_walked_again():
    import numpy as np

    from qz_drake.capability.relabel import _unchanged

    arrays = {"index": np.array([0, 0, 1, 1, 2, 3, 4]), "status": np.array(["executed"] * 4 + ["invalid", "executed", "error"]),
              "blc_success": np.array([True, True, True, False, False, True, False]),
              "success": np.array([True, True, True, False, False, False, False])}
    same, others = _unchanged(arrays)
    # 0 walked all; 1 was refused; 2 never stood (the same under any ladder); 3 failed walking; 4 crashed.
    assert same == {0, 2} and others == {1, 3, 4}


def test_relabelling_refuses_what_it_cannot_relabel(tmp_path):
    import json

    from qz_drake.capability.relabel import relabel

    folder = tmp_path / "moves"
    folder.mkdir()
    (folder / "manifest.json").write_text(json.dumps({"format": "qz_drake.capability.dataset/1", "seed": 0,
                                                      "settings": {}, "fingerprints": {}, "shards": []}))
    with pytest.raises(QzError, match="moves dataset"):
        relabel(folder, tmp_path / "out", blc_ladder="cycles+1")
    manifest = json.loads((folder / "manifest.json").read_text())
    manifest["settings"] = {"protocol": "episodes", "blc_ladder": "cycles+1"}
    (folder / "manifest.json").write_text(json.dumps(manifest))
    with pytest.raises(QzError, match="--blc-ladder.*source's own"):
        relabel(folder, tmp_path / "out", blc_ladder=" cycles+1")
    assert not (tmp_path / "out").exists()


# Two flat episodes walked, one checked and one walked again with the ladder: about 40 s.
@pytest.mark.slow
def test_an_episode_dataset_relabelled_with_the_ladder(tmp_path):
    import json

    import numpy as np

    from qz_drake.capability.dataset import load_records
    from qz_drake.capability.relabel import relabel

    from qz_drake.capability.collect import _protocol_functions, collect_units
    from qz_drake.capability.dataset import settings_dict
    from qz_drake.capability.episodes import episode_specs

    source = tmp_path / "episodes"
    scene = _flat_spec().scene
    # The flat scene's nominal and hind_bend episodes (every mission walked at 30 iterations).

    specs = [s for s in episode_specs(0, scene + 1, topologies=["nominal", "hind_bend"]) if s.scene == scene]
    settings = dict(settings_dict(TrialConfig()), protocol="episodes")
    function, crashed = _protocol_functions("episodes")
    collect_units(source, specs, seed=0, settings=settings, config=TrialConfig(), function=function, crashed=crashed,
                  unit="episodes", progress=False)
    stored, _ = load_records(source)
    assert stored["blc_success"].all() and stored["success"].all()
    # Stored as if the hind_bend episode's second mission had been refused (a shard edited here).
    manifest = json.loads((source / "manifest.json").read_text())
    shard = source / manifest["shards"][0]["file"]
    with np.load(shard) as data:
        arrays = {k: data[k] for k in data.files}
    hit = np.flatnonzero((arrays["topology"] == "hind_bend") & (arrays["heading_sample"] == 1))[0]
    arrays["blc_success"][hit] = arrays["success"][hit] = False
    np.savez_compressed(shard, **arrays)
    out = tmp_path / "laddered"
    summary = relabel(source, out, blc_ladder="cycles+1,split", verify=1, progress=False)
    assert summary.planned == 2 and summary.ran == 1
    got, manifest = load_records(out)
    assert manifest["settings"]["blc_ladder"] == "cycles+1,split" and manifest["relabel_verified"]["episodes"]
    assert manifest["settings"]["relabelled_from"]["dataset"] == str(source)
    # The nominal episode copied as it was; the hind_bend one walked again: every mission walked.
    nominal = got["topology"] == "nominal"
    np.testing.assert_array_equal(got["patch"][nominal], stored["patch"][stored["topology"] == "nominal"])
    assert got["blc_success"][~nominal].all() and got["success"][~nominal].all()
    # Resumed: nothing left to do.
    assert relabel(source, out, blc_ladder="cycles+1,split", progress=False).ran == 0
    # Recertified like any dataset (its source in the settings is not a trial setting).
    from qz_drake.capability.collect import recertify

    manifest = json.loads((out / "manifest.json").read_text())
    manifest["fingerprints"]["blc"] = "0123456789abcdef"
    (out / "manifest.json").write_text(json.dumps(manifest))
    result = recertify(out, sample=1)
    assert result.identical and result.rerun == 1, result.mismatches
