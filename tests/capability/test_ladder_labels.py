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
