"""The comparison of paper 000 Fig. 9: top-level controllers on the same BLC, executed in Drake.

"They share the same BLC of CapPlanner, but different TLC." One module a job:

* ``tasks.py``: ExperimentConfig, TaskSpec, ``PLANNERS`` and ``run_task``, one task walked to its record.
* ``results.py``: a results folder's files, its records and the settings its walks had.
* ``comparison.py``: the paired comparison of the planners, McNemar's exact test and the aim.
* ``run.py``: ``run_experiment``, a whole run into a results folder (resumable).
* ``tune.py``: ``tune_astar`` / ``tune_capplanner``, each planner's settings chosen on tuning worlds.
* ``predict.py``: what CapPlanner's model expected of each task, and its route calibration.
* ``reporting.py``: ``report`` / ``report_markdown``, the report of a results folder.

Each module imports only those above it in this list; the names callers use are handed on here.
"""

from qz_drake.experiments.fig9.comparison import claim_check, compare_planners, compare_runs, summarise
from qz_drake.experiments.fig9.predict import predict_route, predict_routes, route_calibration, route_calibration_check
from qz_drake.experiments.fig9.reporting import (discordant_pictures, discordant_tasks, planner_differences,
                                                 report, report_markdown)
from qz_drake.experiments.fig9.results import (MODEL_IDENTITY, PREDICTIONS, RESULTS, read_config, read_results,
                                               read_settings)
from qz_drake.experiments.fig9.run import run_experiment
from qz_drake.experiments.fig9.tasks import (EXPERIMENT_PLANNERS, PLANNERS, ExperimentConfig, TaskSpec, path_samples,
                                             run_task)
from qz_drake.experiments.fig9.tune import (TUNING_BODY_RADII, TUNING_DIFFICULTIES, TUNING_FAILURE_REWARDS,
                                            TUNING_MERGE_MIN_SUCCESS, TUNING_MISSION_LENGTHS,
                                            TUNING_PESSIMISMS, TUNING_PLAN_FAILURE_RISKS, TUNING_SLOPES_DEG,
                                            TUNING_STEP_HEIGHTS,
                                            TUNING_TASKS_PER_CELL, TUNING_TOPOLOGY_CHANGE_COSTS,
                                            TUNING_TOPOLOGY_DOUBTS, astar_settings, capplanner_settings,
                                            tune_astar, tune_capplanner)

__all__ = [
    "ExperimentConfig", "TaskSpec", "PLANNERS", "EXPERIMENT_PLANNERS", "run_task", "path_samples", "RESULTS", "PREDICTIONS",
    "MODEL_IDENTITY", "read_results", "read_settings", "read_config", "run_experiment", "summarise", "compare_planners",
    "claim_check", "compare_runs", "predict_route", "predict_routes", "route_calibration", "route_calibration_check",
    "report", "report_markdown", "planner_differences", "discordant_tasks", "discordant_pictures", "tune_astar",
    "tune_capplanner", "astar_settings", "capplanner_settings", "TUNING_TASKS_PER_CELL", "TUNING_DIFFICULTIES",
    "TUNING_STEP_HEIGHTS", "TUNING_SLOPES_DEG", "TUNING_BODY_RADII", "TUNING_FAILURE_REWARDS",
    "TUNING_TOPOLOGY_CHANGE_COSTS", "TUNING_PLAN_FAILURE_RISKS", "TUNING_MISSION_LENGTHS",
    "TUNING_MERGE_MIN_SUCCESS", "TUNING_TOPOLOGY_DOUBTS", "TUNING_PESSIMISMS",
]
