"""CapPlanner as a walk's route source (paper 000 II-E.2): the CapabilityVIPlanner that hands
TrajectoryOptimizationBLC its local targets, built for a walking scenario.

``qz_drake.simulation.walk`` builds, runs and judges a walk given its route source; it knows
the fixed route (``FixedRoute``) and nothing above it. Callers that walk CapPlanner scenarios
(the ``qz`` commands, the demo, the Fig. 9 experiment) pass ``route_source_for(scenario)``.
"""

from __future__ import annotations

import dataclasses

from qz_drake.capability.model import CapabilityModel
from qz_drake.capability.patches import KINDS, map_stance
from qz_drake.capability.trials import TrialConfig, trial_blc_parameters
from qz_drake.errors import bad_value
from qz_drake.planning.capability_mdp import CapabilityMdpConfig
from qz_drake.planning.capability_planner import CapabilityVIPlanner, check_hold_margin, check_revisit_cost
from qz_drake.planning.guidance import MissionSplitConfig, check_target_shift
from qz_drake.robot.topology import TOPOLOGY_NAMES
from qz_drake.scene import check_standable
from qz_drake.simulation import FixedRoute
from qz_drake.state_layout import BASE_XY, base_rpy

# CapPlanner's walks solve a mission that failed to plan again, up to this often, each time one
# tripod cycle longer (TrajectoryOptimizationBLC's mission_retries). A long_range walk ended at
# its third mission on the BLC's dense check (a stance foot 2 mm outside its kinematic box at
# one 100 Hz sample); 46 of the first 5800 capability trials failed the same way, by 2-6 mm or
# a residual of 0.05-0.08 body weights. The robot stands while the BLC solves, so a retry costs
# wall time only. The capability trials keep 0: their labels are the BLC's first solves, so
# the learned success rates are, if anything, cautious for a walk that retries.
CAPPLANNER_MISSION_RETRIES = 2


def mdp_config(overrides: dict, topologies, stance: str = "nominal") -> CapabilityMdpConfig:
    """CapPlanner's MDP settings: the defaults, ``overrides`` (controller.capability_mdp) by
    name, the topologies the model knows, the stance its map assumes (CapabilityMdpConfig.stance).
    A switch (``topology_doubt``) is given as 1 or 0 (the scenario's settings there are numbers)."""
    fields = {f.name: f.type for f in dataclasses.fields(CapabilityMdpConfig)}
    numbers = [name for name, kind in fields.items() if kind in ("float", float, "bool", bool)]
    values = {}
    for key, value in overrides.items():
        if key not in numbers:
            raise bad_value(f"scenario.controller.capability_mdp.{key}", value,
                            f"not a setting of the MDP (valid: {', '.join(numbers)})")
        if fields[key] in ("bool", bool):
            if value not in (0, 1):  # True and False compare equal to 1 and 0
                raise bad_value(f"scenario.controller.capability_mdp.{key}", value, "must be 1 (on) or 0 (off)")
            values[key] = bool(value)
        else:
            values[key] = float(value)
    return CapabilityMdpConfig(topologies=list(topologies), stance=stance, **values).check()


def check_topologies(names, field: str) -> tuple[str, ...]:
    """``names`` (a tuple, or a comma-separated string) as a tuple of topology names; a name
    that is none names ``field``."""
    names = tuple(n for n in names.split(",") if n) if isinstance(names, str) else tuple(names)
    for name in names:
        if name not in TOPOLOGY_NAMES:
            raise bad_value(field, name, f"not a topology (valid: {', '.join(TOPOLOGY_NAMES)})")
    return names


class CapPlannerRoute(FixedRoute):
    """CapPlanner's top-level controller as a walk's route source: the capability model of
    ``controller.capability_model`` (empty: the shipped one), the goal at the route's last
    waypoint (its heading the planner's to choose), planned over the station's heightmap from
    the robot's start. The BLC solves as the capability model learned it (the trials'
    iteration budget) and retries a mission CAPPLANNER_MISSION_RETRIES times. ``split_config``
    (guidance.MissionSplitConfig: the longest mission, the merge threshold) is the planner's
    split of its path into missions (None: the defaults); ``min_route_success`` the least
    predicted chance of arriving without a fall for which it sets out (CapabilityVIPlanner);
    ``back_out`` whether it backs out of a dead end (qz_drake.planning.back_out);
    ``measured_stance`` whether each replan judges the first moves from the robot's stance,
    ``refused_in_every_topology`` whether a refused move is closed in every topology,
    ``hold_margin`` how much more a replan's route must be worth to replace the current one
    (CapabilityVIPlanner); ``route_check`` how many missions ahead each route is planned by the
    walk's BLC before it is handed out (qz_drake.planning.route_check; 0: none), a refused one
    solved again on ``check_ladder`` (the walk's ladder, or its retries' rungs); ``topologies``
    the topologies it may plan in (empty: every one the model knows; ``("nominal",)``: the
    robot never changes topology, what switching buys is measured against); ``revisit_cost``
    what a move into a cell costs more for each mission that ended there, ``target_shift`` how
    far a mission's target may move from its cell's centre away from edges (CapabilityVIPlanner)."""

    mission_retries = CAPPLANNER_MISSION_RETRIES
    chooses_goal_heading = True
    name = "CapPlanner"

    def __init__(self, split_config: MissionSplitConfig | None = None, min_route_success: float = 0.05,
                 back_out: bool = True, measured_stance: bool = True, refused_in_every_topology: bool = True,
                 hold_margin: float | None = None, route_check: int = 0, check_ladder=(), topologies=(),
                 revisit_cost: float = 0.0, target_shift: float = 0.0):
        from qz_drake.errors import bad_value
        from qz_drake.planning.route_check import check_route_check
        from qz_drake.systems.blc_plan import parse_ladder

        self._split = (split_config or MissionSplitConfig()).check()
        if not 0.0 <= float(min_route_success) <= 1.0:
            raise bad_value("min_route_success", min_route_success, "must be in [0, 1]")
        self.min_route_success = float(min_route_success)
        self.back_out = bool(back_out)
        self.measured_stance = bool(measured_stance)
        self.refused_in_every_topology = bool(refused_in_every_topology)
        self.hold_margin = check_hold_margin(hold_margin)
        self.route_check = check_route_check(route_check)
        self.check_ladder = parse_ladder(check_ladder, "check_ladder")
        self.topologies = check_topologies(topologies, "topologies")
        self.revisit_cost = check_revisit_cost(revisit_cost)
        self.target_shift = check_target_shift(target_shift)

    def blc_parameters(self):
        # The BLC the capability model learned: the trials' deterministic budget (30 Ipopt
        # iterations, not 5 s of wall time, which a loaded machine spends in fewer), so that
        # a walk plans what the model predicts, whatever else the machine runs.
        return trial_blc_parameters(TrialConfig())

    def make(self, scenario, info, targets, blc_params=None) -> CapabilityVIPlanner:
        from qz_drake.planning.route_check import route_check_for
        from qz_drake.systems.mission_sequencer import measured_start

        control = scenario.controller
        blc_params = blc_params or self.blc_parameters()
        # The map asks about the stance the BLC's missions end in.
        stance = map_stance(blc_params.terminal_stance)
        model = CapabilityModel.load(control.capability_model or None)
        # The topologies the model knows all three moves of (of those the route may use).
        topologies = [t for t in TOPOLOGY_NAMES if all(model.has_network(t, k) for k in KINDS)
                      and (not self.topologies or t in self.topologies)]
        if info.topology.name not in topologies:
            raise bad_value("scenario.robot.topology", info.topology.name,
                            f"the capability model has no networks for it or the route may not use it (it may "
                            f"use {', '.join(topologies) or 'none'})")
        x0 = info.initial_state
        goal = control.route[-1]
        check_standable(info.heightmap, (goal.x, goal.y), info.topology.name,
                        f"scenario.controller.route[{len(control.route) - 1}]")
        start_x, start_y = x0[BASE_XY]
        check = route_check_for(self.route_check, info.heightmap, info.params, control.timing, blc_params,
                                self.check_ladder)
        return CapabilityVIPlanner(model=model, heightmap=info.heightmap, goal=(goal.x, goal.y),
                                   start=(float(start_x), float(start_y), float(base_rpy(x0)[2])),
                                   initial_topology=info.topology.name, plan_ahead=control.plan_ahead,
                                   mdp_config=mdp_config(control.capability_mdp, topologies, stance),
                                   split_config=self._split, min_route_success=self.min_route_success,
                                   back_out=self.back_out, measured_stance=self.measured_stance,
                                   refused_in_every_topology=self.refused_in_every_topology,
                                   hold_margin=self.hold_margin, route_check=check, revisit_cost=self.revisit_cost,
                                   check_start=None if check is None else measured_start(x0, 0.0, info.params),
                                   target_shift=self.target_shift)

    def unreachable(self, source) -> str:
        return source.log.unreachable

    def add_visuals(self, builder, source, meshcat, info) -> None:
        # The guidance path in the recording, replaced at each replan.
        from qz_drake.viz.guidance_path import add_guidance_visualizer

        add_guidance_visualizer(builder, source.GetOutputPort("guidance"), meshcat, info.heightmap)

    def plots(self, source, scenario, info, states, out) -> dict:
        if source.first_plan is None:
            return {}
        from qz_drake.capability.plots import plot_plan

        return {"plan": str(plot_plan(info.heightmap, source.first_plan, out / "plan.png",
                                      title=f"{scenario.name}: CapPlanner's plan from the start and the walk",
                                      walked_xy=states[:, BASE_XY]))}


def route_source_for(scenario) -> FixedRoute | None:
    """The route source of a scenario's ``controller.planner``: CapPlanner's for "capplanner",
    the fixed route's for "blc", None for the kinematic tripod plan (it has none)."""
    planner = scenario.controller.planner
    return CapPlannerRoute() if planner == "capplanner" else FixedRoute() if planner == "blc" else None
