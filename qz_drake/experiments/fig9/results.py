"""A results folder of the Fig. 9 experiment: its file names, its records and the settings its
walks had.

``results.jsonl`` holds one record per task (run.py appends them as tasks finish),
``settings.json`` the ExperimentConfig they were walked with (and the capability model's
identity), ``predictions.jsonl`` the routes CapPlanner's model expected (predict.py).
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

from qz_drake.errors import bad_value
from qz_drake.experiments.fig9.tasks import ExperimentConfig

# One record per task, appended as tasks finish.
RESULTS = "results.jsonl"
# One predicted route per CapPlanner task (predict.predict_routes).
PREDICTIONS = "predictions.jsonl"
# settings.json's record of the capability model CapPlanner's walks used (CapabilityModel.identity).
MODEL_IDENTITY = "capability_model_identity"


# Settings whose coming changed what the walks do, with the value that results written before
# them were walked with: a folder without the setting holds those walks, not today's default's.
# A* had no recovery before issue 38; CapPlanner declined paths whose predicted chance of no
# fall was below 0.05 (CapabilityVIPlanner's default).
SETTINGS_BEFORE_THEY_EXISTED = {"astar_max_recoveries": 0, "capplanner_min_route_success": 0.05,
                                "recovery_back_out": False, "capplanner_topology_doubt": False,
                                "capplanner_measured_stance": False, "capplanner_refused_in_every_topology": False,
                                "blc_ladder": "", "blc_terminal_stance": "free", "capplanner_edge_cost": 0.0,
                                "route_check": 0, "capplanner_turns_with_moves": False,
                                "capplanner_topologies": "", "capplanner_turn_edge_risk": 0.0,
                                "capplanner_revisit_cost": 0.0, "capplanner_target_shift": 0.0,
                                "blc_leg_clearance_softmin": None, "control_mode": "torque", "time_step": 0.002}


def read_json_lines(path) -> list[dict]:
    """The records of a JSON-lines file that is appended to a record at a time ([] without the
    file). A last line without its newline that does not parse is a record whose writing was cut
    off (a run killed mid-write, or one still writing it): left out, so its task counts as not
    done. Any other line that does not parse is damage no run leaves: a QzError naming the file
    and the line."""
    path = Path(path)
    if not path.is_file():
        return []
    text = path.read_text()
    lines = text.split("\n")
    records = []
    for number, line in enumerate(lines, 1):
        if not line.strip():
            continue
        try:
            records.append(json.loads(line))
        except json.JSONDecodeError as e:
            if number == len(lines):  # the last line, without its newline: cut off
                break
            raise bad_value(f"{path} line {number}", line[:60], f"is not a JSON record ({e.msg})") from None
    return records


def drop_cut_off_record(path) -> bool:
    """Makes a JSON-lines file ready for more records: a last line without its newline that
    does not parse (a record whose writing was cut off) is cut away, and True returned; one that
    parses (only its newline was lost) gets its newline, as :func:`read_json_lines` counts it."""
    path = Path(path)
    if not path.is_file() or path.stat().st_size == 0:
        return False
    with path.open("rb+") as f:
        data = f.read()
        if data.endswith(b"\n"):
            return False
        start = data.rfind(b"\n") + 1
        try:
            json.loads(data[start:])
        except ValueError:  # JSONDecodeError, or bytes that are not UTF-8
            f.truncate(start)
            return True
        f.write(b"\n")
    return False


def read_results(out) -> list[dict]:
    """The records of a results folder, in the order they were written ([] before the first;
    a last record cut off in writing left out: :func:`read_json_lines`)."""
    return read_json_lines(Path(out) / RESULTS)


def read_settings(out: Path) -> dict:
    """The settings a results folder's walks had ({} without settings.json)."""
    path = out / "settings.json"
    return {**SETTINGS_BEFORE_THEY_EXISTED, **json.loads(path.read_text())} if path.is_file() else {}


def read_config(out) -> ExperimentConfig:
    """The ExperimentConfig a results folder's walks had (its settings.json; the defaults for
    what it does not name)."""
    names = {f.name for f in dataclasses.fields(ExperimentConfig)}
    return ExperimentConfig(**{k: v for k, v in read_settings(Path(out)).items() if k in names})
