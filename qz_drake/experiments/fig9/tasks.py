"""One task of paper 000 Fig. 9 planned and walked in Drake: top-level controllers on the same BLC.

"They share the same BLC of CapPlanner, but different TLC." A task is walked by its planner's
route (``PLANNERS``), in BLC missions of at most 1 m, tracked by IK and joint PD, judged by the
strict verdict, within a simulated-time budget; the record holds success, reason, walked path
length, straight-line distance, displacement ratio (walked / straight), missions, replans,
topology changes and wall time. ``ExperimentConfig`` holds the settings every task of a run
shares.
"""

from __future__ import annotations

import dataclasses
import time

import numpy as np

from qz_drake.config import MissionTiming, WalkDrives, drive_station
from qz_drake.state_layout import BASE_XY
from qz_drake.experiments.worlds import make_task
from qz_drake.trajopt.parameters import BlcParameters


@dataclasses.dataclass(frozen=True)
class ExperimentConfig:
    """Settings shared by every task of a run (part of each record)."""

    # Mission length, speed and tripod phase of the BLC missions. [m], [m/s], [s]
    mission_length: float = 1.0
    speed: float = MissionTiming.speed
    phase_duration: float = MissionTiming.phase_duration
    # Simulated-time budget: this many times the straight-line walking time, plus a margin. [-], [s]
    time_factor: float = 2.5
    time_margin: float = 20.0
    # The BLC's budget per mission (as the capability trials: deterministic). [iterations], [s]
    blc_max_iterations: int = 30
    blc_time_limit: float = 30.0
    # How often a mission the BLC could not plan is solved again, one tripod cycle longer each
    # time, for both planners alike (TrajectoryOptimizationBLC's mission_retries), before the
    # planner's recovery hears of the refusal. 0: first solves only, the capability trials' BLC.
    # Of 9 refusals in CapPlanner's walks of three hard tuning worlds, one tripod cycle longer
    # planned 4, the same mission with 200 Ipopt iterations instead of 30 none (BENCHMARKS
    # "fig9", session 40).
    blc_retries: int = 0
    # The BLC ladder instead (TrajectoryOptimizationBLC's ``ladder``, e.g. "cycles+1,split"), for
    # both planners alike; "": the retries'. Not with blc_retries.
    blc_ladder: str = ""
    # Where the feet stand when each mission ends (BlcParameters.terminal_stance), for both
    # planners alike: "free" (every run before issue 54) or "canonical" (trajopt/stance.py;
    # CapPlanner's map then asks about the same stance, capability_mdp.CapabilityMdpConfig.stance).
    blc_terminal_stance: str = "free"
    # The legs' clearance as one smooth-minimum row per leg and sample of this sharpness
    # (BlcParameters.leg_clearance_softmin, whose default this is), for both planners alike;
    # None: a row per link point. [1/m]
    blc_leg_clearance_softmin: float | None = BlcParameters.leg_clearance_softmin
    # CapPlanner's capability model folder; empty: the shipped one.
    capability_model: str = ""
    # World scale (1: the experiment; smaller: tiny tasks for tests, see worlds.make_task).
    scale: float = 1.0
    # The A* baseline's thresholds and safety weight (astar_baseline.AStarBaselineConfig),
    # chosen by ``qz experiment tune-astar`` on worlds that are not the experiment's.
    astar_max_step_height: float = 0.2
    astar_max_slope_deg: float = 30.0
    astar_safety_weight: float = 0.5
    astar_body_radius: float = 0.7
    # The learned A* (planner ``astar_learned``, issue 54's baseline from the field): A*'s
    # geometric search with CapPlanner's model as an edge cost and veto
    # (astar_baseline.LearnedCost: the weight on -log of a grid move's predicted success, and the
    # least predicted success A* may take); otherwise A*'s thresholds and recovery. Chosen on the
    # 24 tuning tasks (session 48, BENCHMARKS "capplanner, learned A*"): weight 3 without a veto
    # walked 20 (A* 18), weight 10 17, weight 10 with a veto at 0.5 14 (8 hard worlds left without
    # a route); on 24 validation tasks (seeds 500-503) weight 3 walked 18, A* 17, CapPlanner 20.
    astar_learned_weight: float = 3.0
    astar_learned_veto: float = 0.0
    # Missions the BLC could not plan that A* goes round (experiments/astar_recovery.py, issue
    # 38): the same number CapPlanner's TLC does (4); 0: A* stops at the first (the first
    # Fig. 9 run's baseline).
    astar_max_recoveries: int = 4
    # Both planners back out of a dead end, a stance from which going round finds no way on
    # (qz_drake.planning.back_out, session 38); False: as before.
    recovery_back_out: bool = True
    # CapPlanner's risk and topology-change settings (capability_mdp.CapabilityMdpConfig's
    # failure_reward and topology_change_cost), chosen by ``qz experiment tune-capplanner`` on
    # the same tuning worlds as A*'s.
    capplanner_failure_reward: float = -100.0
    capplanner_topology_change_cost: float = 2.0
    # The share of predicted planning failures CapPlanner counts as falls
    # (capability_mdp.CapabilityMdpConfig.plan_failure_risk).
    capplanner_plan_failure_risk: float = 0.0
    # Whether CapPlanner doubts a topology change by the ensemble's disagreement about the
    # difference between the topologies (capability_mdp.CapabilityMdpConfig.topology_doubt).
    capplanner_topology_doubt: bool = True
    # How far CapPlanner doubts an action's success by the ensemble's spread
    # (capability_mdp.CapabilityMdpConfig.pessimism: p - pessimism * spread).
    capplanner_pessimism: float = 1.0
    # What CapPlanner's MDP charges a move or turn for passing near an edge
    # (capability_mdp.CapabilityMdpConfig.edge_cost; session 49): 0, none, as every run before.
    capplanner_edge_cost: float = 0.0
    # The risk of a turn beside an edge that CapPlanner's MDP adds to the model's
    # (capability_mdp.CapabilityMdpConfig.turn_edge_risk: at most this on the edge, none beyond
    # 0.4 m), measured on the tuning walks' recorded turns (session 53, data/turn_edge_risk:
    # turns in place from within 0.2 m of a box's side failed walking 43 % of the time, the model
    # said 0.2 %). With it CapPlanner walked 22 of the 24 tuning tasks against 21, and 9 of 16
    # validation tasks on hard box fields against 8, losing none. 0: the model's turns.
    capplanner_turn_edge_risk: float = 0.5
    # What a move into a cell costs CapPlanner more for each mission that ended there
    # (CapabilityVIPlanner's revisit_cost; session 53). 0: none, as every run before.
    capplanner_revisit_cost: float = 0.0
    # How far CapPlanner's mission targets but the goal move from their cell's centre, away from
    # edges (CapabilityVIPlanner's target_shift; session 54). 0: the cell centres, as every run before.
    capplanner_target_shift: float = 0.0
    # Whether CapPlanner judges the first moves of each replan from the stance the robot stands
    # in, and backs out of a dead end the model foretells (CapabilityVIPlanner's measured_stance).
    capplanner_measured_stance: bool = True
    # Whether a move the BLC refused is closed in every topology from that cell and heading
    # (CapabilityVIPlanner's refused_in_every_topology, session 39); False: CapPlanner may
    # try it again in another topology.
    capplanner_refused_in_every_topology: bool = True
    # CapPlanner's split of its path into BLC missions (guidance.MissionSplitConfig): the
    # longest mission [m] and the least predicted success of a merged mission.
    capplanner_mission_length: float = 2.0
    capplanner_merge_min_success: float = 0.8
    # Whether a turn in place that the merge threshold would leave alone goes with the move
    # after it (guidance.MissionSplitConfig.turns_with_moves; session 52). False: as before.
    capplanner_turns_with_moves: bool = True
    # The topologies CapPlanner may plan in, comma-separated (CapPlannerRoute's topologies);
    # empty: every one the model knows, as every run before session 52; "nominal": it never
    # changes topology (what switching buys, issue 54).
    capplanner_topologies: str = ""
    # The least predicted chance of arriving without a fall for which CapPlanner sets out
    # (CapabilityVIPlanner's min_route_success). 0: it never declines a task it has a path for,
    # as A* never declines one it has a route for; a declined task is a failed one here.
    capplanner_min_route_success: float = 0.0
    # A replan at a mission's end keeps CapPlanner's route unless the new one is worth more
    # than this (CapabilityVIPlanner's hold_margin, value units); None: every replan takes the
    # policy's path, as the paper's TLC (and every run before issue 54).
    capplanner_hold_margin: float | None = None
    # Missions ahead that both planners alike plan with the walk's BLC (its parameters and
    # ladder) before handing a route out, going round a refusal foreseen there as round one met
    # (qz_drake.planning.route_check; issue 54). 0: none, as every run before session 51.
    route_check: int = 0
    # Keep every mission of every walk in its record (``missions``: where it started, its
    # target, its outcome; capability.walk_missions), for scoring a capability model on whole
    # walks (issue 37). Off for the experiment itself (the records stay small).
    record_missions: bool = False
    # How the joints are driven in every walk, for both planners alike, and the plant's step,
    # as the capability trials have them (capability.trials.TrialConfig's control_mode and
    # time_step, which label a dataset; config.WalkDrives, the default): "position", Eq. 7's PD
    # (ControllerConfig's kp and kd) in the drives on the tracker's q_des and v_des (the plant's
    # implicit PD actuators); "torque", the same PD computed by the controller at every step of
    # at most 2 ms (every run before issue 53's drives). [s]
    control_mode: str = WalkDrives.control_mode
    time_step: float = WalkDrives.time_step


def check_drives(control_mode, time_step) -> None:
    """The walks' drives (ExperimentConfig.control_mode, time_step) as the trials check theirs,
    errors named by the command's options."""
    from qz_drake.capability.trials import MAX_EXPLICIT_PD_STEP, MAX_TRIAL_STEP
    from qz_drake.config import CONTROL_MODES
    from qz_drake.errors import bad_value

    if control_mode not in CONTROL_MODES:
        raise bad_value("--control-mode", control_mode, f"expected one of {', '.join(CONTROL_MODES)}")
    if isinstance(time_step, bool) or not isinstance(time_step, (int, float)) or not 0 < time_step <= MAX_TRIAL_STEP:
        raise bad_value("--time-step", time_step, f"expected a step in (0, {MAX_TRIAL_STEP:g}] s")
    if control_mode == "torque" and time_step > MAX_EXPLICIT_PD_STEP:
        raise bad_value("--time-step", time_step, f"the explicit joint PD (--control-mode torque) needs steps of at "
                                                  f"most {MAX_EXPLICIT_PD_STEP:g} s; use --control-mode position "
                                                  f"for longer ones")


@dataclasses.dataclass(frozen=True)
class TaskSpec:
    terrain: str
    difficulty: str
    seed: int
    planner: str
    # A folder for the walk's recording (recording.html, metrics.json, plots); empty: none.
    record_dir: str = ""

    @property
    def key(self) -> str:
        return f"{self.terrain}-{self.difficulty}-{self.seed}-{self.planner}"


def _astar(task, config, learned=None):
    """A* over the geometric cost map: a route in the nominal topology (planner blc), walked
    with the recovery of experiments/astar_recovery.py (``astar_max_recoveries``); ``learned``
    (astar_baseline.LearnedCost) adds the model's answers to the cost map."""
    import time

    from qz_drake.experiments.astar_baseline import AStarBaseline, AStarBaselineConfig
    from qz_drake.experiments.astar_recovery import AStarRoute

    clock = time.perf_counter()
    baseline = AStarBaseline(task.heightmap, AStarBaselineConfig(max_step_height=config.astar_max_step_height,
                                                                 max_slope_deg=config.astar_max_slope_deg,
                                                                 safety_weight=config.astar_safety_weight,
                                                                 body_radius=config.astar_body_radius,
                                                                 waypoint_spacing=config.mission_length),
                             learned=learned(task) if learned is not None else None)
    route = baseline.route(task.start, task.goal)
    route = dataclasses.replace(route, planning_time_s=time.perf_counter() - clock)
    return route, "blc", route.waypoints, AStarRoute(baseline, task.goal, config.astar_max_recoveries,
                                                     back_out=config.recovery_back_out,
                                                     route_check=config.route_check, check_ladder=_walk_ladder(config))


def _astar_learned(task, config):
    """The learned A*: A* with CapPlanner's model as an edge cost and veto, its capability map
    of the nominal topology made from the task's start (as CapPlanner's, in the stance the
    BLC's missions end in); the route and recovery are A*'s, the map's time part of planning."""
    from qz_drake.capability.model import CapabilityModel, predict_map
    from qz_drake.capability.patches import map_stance
    from qz_drake.experiments.astar_baseline import LearnedCost

    def learned(task):
        model = CapabilityModel.load(config.capability_model or None)
        capability_map = predict_map(model, task.heightmap, ["nominal"], anchor=task.start,
                                     stance=map_stance(config.blc_terminal_stance))
        return LearnedCost(capability_map, config.astar_learned_weight, config.astar_learned_veto)

    return _astar(task, config, learned)


def _capplanner(task, config):
    """CapPlanner's TLC in the diagram (planner capplanner): the goal is the only waypoint."""
    from qz_drake.experiments.astar_baseline import Route
    from qz_drake.planning.capplanner_route import CapPlannerRoute
    from qz_drake.planning.guidance import MissionSplitConfig

    split = MissionSplitConfig(max_length=config.capplanner_mission_length,
                               min_success=config.capplanner_merge_min_success,
                               turns_with_moves=config.capplanner_turns_with_moves)
    return (Route(True, "", [], 0.0, np.zeros((0, 2))), "capplanner", [(*task.goal, 0.0, "nominal")],
            CapPlannerRoute(split, min_route_success=config.capplanner_min_route_success,
                            back_out=config.recovery_back_out, measured_stance=config.capplanner_measured_stance,
                            refused_in_every_topology=config.capplanner_refused_in_every_topology,
                            hold_margin=config.capplanner_hold_margin, route_check=config.route_check,
                            check_ladder=_walk_ladder(config),
                            topologies=config.capplanner_topologies,
                            revisit_cost=config.capplanner_revisit_cost,
                            target_shift=config.capplanner_target_shift))


def _walk_ladder(config: ExperimentConfig) -> tuple[str, ...]:
    """The rungs the walks' BLC solves a refused mission again on: the ladder, or the retries'."""
    from qz_drake.systems.blc_plan import parse_ladder, retry_ladder

    return parse_ladder(config.blc_ladder, "--blc-ladder") if config.blc_ladder else retry_ladder(config.blc_retries)


def _mdp_overrides(config: ExperimentConfig) -> dict:
    """CapPlanner's MDP settings of a run (scenario.controller.capability_mdp)."""
    return dict(failure_reward=config.capplanner_failure_reward,
                topology_change_cost=config.capplanner_topology_change_cost,
                plan_failure_risk=config.capplanner_plan_failure_risk,
                topology_doubt=float(config.capplanner_topology_doubt), pessimism=config.capplanner_pessimism,
                edge_cost=config.capplanner_edge_cost, turn_edge_risk=config.capplanner_turn_edge_risk)


# Top-level controllers: name -> (task, config) -> (Route, walking planner, waypoints, route
# source of the walk or None: the scenario's own, qz_drake.planning.capplanner_route.route_source_for).
PLANNERS = {"astar": _astar, "capplanner": _capplanner, "astar_learned": _astar_learned}
# The two of paper 000's Fig. 9, which a run walks unless told otherwise.
EXPERIMENT_PLANNERS = ("astar", "capplanner")
# The planners that ask the capability model.
MODEL_PLANNERS = ("capplanner", "astar_learned")


def run_task(spec: TaskSpec, config: ExperimentConfig = ExperimentConfig()) -> dict:
    """Plans and walks one task; returns its record (never raises for a failed walk)."""
    from qz_drake.config import (ControllerConfig, RobotConfig, Scenario, SimulationConfig,
                                 TerrainConfig, Waypoint)
    from qz_drake.planning.capability_planner import ROUTE_DECISIONS, route_count_key
    from qz_drake.planning.capplanner_route import route_source_for
    from qz_drake.simulation import walk

    clock = time.perf_counter()
    task = make_task(spec.terrain, spec.difficulty, spec.seed, scale=config.scale)
    record = {"key": spec.key, "terrain": spec.terrain, "difficulty": spec.difficulty, "seed": spec.seed,
              "planner": spec.planner, "straight_m": task.distance, "success": False, "reason": "",
              "message": "", "walked_m": 0.0, "displacement_ratio": None, "missions": 0, "replans": 0,
              "recoveries": 0, "back_outs": 0, "topology_changes": 0, "planning_time_s": 0.0, "wall_time_s": 0.0,
              "error": ""}
    try:
        route, walking_planner, waypoints, route_source = PLANNERS[spec.planner](task, config)
        record["planning_time_s"] = route.planning_time_s
        if not route.found:
            record.update(reason="planner", message=route.reason)
            return record
        # Both planners walk on the whole world (CapPlanner may detour anywhere on it).
        xmin, xmax, ymin, ymax = task.heightmap.bounds
        region = [xmin, xmax, ymin, ymax]
        budget = config.time_factor * task.distance / config.speed + config.time_margin
        controller = ControllerConfig(kind="walk", planner=walking_planner, mission_length=config.mission_length,
                                      speed=config.speed, phase_duration=config.phase_duration,
                                      capability_model=config.capability_model,
                                      capability_mdp=_mdp_overrides(config),
                                      route=[Waypoint(x=x, y=y, yaw=a, topology=t) for x, y, a, t in waypoints])
        scenario = Scenario(
            name=spec.key, terrain=TerrainConfig(kind="flat", region=region),
            robot=RobotConfig(initial_xy=list(task.start), initial_yaw=task.start_yaw),
            simulation=SimulationConfig(duration=budget, time_step=config.time_step),
            station=drive_station(config.control_mode, controller.kp, controller.kd), controller=controller)
        # One BLC for both planners, as paper 000 has it: first solves only (the trials' BLC, and
        # the one the A* settings were tuned with) unless ``blc_retries`` says otherwise, the
        # same for both; what differs is the TLC, including how it goes round a mission the BLC
        # could not plan.
        if config.record_missions:  # a walk that never started (its first mission refused) keeps none
            record["mission_records"] = []

        def keep_missions(built, run, judged):
            from qz_drake.capability.walk_missions import walk_mission_records

            record["mission_records"] = walk_mission_records(built, run, judged, scenario.success)

        result = walk(scenario, heightmap=task.heightmap, stop_on_failure=True,
                      out_dir=spec.record_dir or None, mission_retries=config.blc_retries,
                      blc_ladder=config.blc_ladder or None,
                      route_source=route_source or route_source_for(scenario),
                      on_judged=keep_missions if config.record_missions else None,
                      blc_params=BlcParameters(max_iterations=config.blc_max_iterations,
                                               time_limit=config.blc_time_limit,
                                               terminal_stance=config.blc_terminal_stance,
                                               leg_clearance_softmin=config.blc_leg_clearance_softmin))
        m = result.metrics
        walked = float(np.sum(np.linalg.norm(np.diff(result.states[:, BASE_XY], axis=0), axis=1))) \
            if len(result.states) > 1 else 0.0
        record.update(success=bool(m["success"]), reason=(m.get("reasons") or [""])[0],
                      message=str(m.get("reason", ""))[:300], walked_m=walked,
                      path_xy=path_samples(result.states[:, BASE_XY]),
                      displacement_ratio=walked / task.distance if m["success"] else None,
                      missions=int(m.get("missions", 0)), topology_changes=int(m.get("topology_changes", 0)),
                      replans=int(m.get("replans", 0)), recoveries=int(m.get("tlc_recoveries", 0)),
                      # Ways back out of a dead end (qz_drake.planning.back_out).
                      back_outs=int(m.get("tlc_back_outs", 0)))
        if config.route_check:
            # Refusals the route check foresaw and went round, and what its solves cost.
            record.update(foreseen=int(m.get("tlc_foreseen_refusals", 0)),
                          route_check_solves=int(m.get("route_check_solves", 0)),
                          route_check_time_s=float(m.get("route_check_time_s", 0.0)))
        if spec.planner == "capplanner":
            record["planning_time_s"] = float(m.get("planning_time_s", 0.0))
            # Replans that walked the most probable path (the MDP's policy did not reach the goal).
            record["most_probable"] = int(m.get("tlc_most_probable", 0))
            # What each replan at a mission's end did with the route (CapabilityPlannerLog.route_decisions).
            record["route_decisions"] = {d: int(m.get(route_count_key(d), 0)) for d in ROUTE_DECISIONS}
    except Exception as e:  # a crash of the run, not an outcome: recorded as an error
        import traceback

        record.update(reason="error", error=f"{type(e).__name__}: {e}\n{traceback.format_exc(limit=3)}"[-600:])
    finally:
        record["wall_time_s"] = time.perf_counter() - clock
    return record


# Spacing of the walked path kept in each record (path_samples). [m]
PATH_SPACING = 0.25


def path_samples(xy, spacing: float = PATH_SPACING) -> list:
    """The base's path [(x, y), ...] [m] at about ``spacing`` along it: the first point, every
    point where the distance walked passes a multiple of ``spacing``, and the last (where a
    failed walk stopped), to the centimetre; a 15 m walk keeps about 60 points."""
    xy = np.asarray(xy, dtype=float).reshape(-1, 2)
    if len(xy) == 0:
        return []
    walked = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(xy, axis=0), axis=1))])
    steps = np.floor(walked / spacing)
    keep = np.flatnonzero(np.concatenate([[True], steps[1:] != steps[:-1]]))
    if keep[-1] != len(xy) - 1:
        keep = np.append(keep, len(xy) - 1)
    return np.round(xy[keep], 2).tolist()
