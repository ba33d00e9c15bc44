"""benchmarks/walks_side_by_side.py: which of a run's walks it re-walks, and when two walks of a
task are the same walk (the check a change that should move no label passes, issue 53)."""

import importlib.util
import json
import sys
from pathlib import Path

import pytest

BENCHMARKS = Path(__file__).resolve().parents[2] / "benchmarks"


def _script():
    sys.path.insert(0, str(BENCHMARKS))  # its tree_runs import
    try:
        spec = importlib.util.spec_from_file_location("walks_side_by_side", BENCHMARKS / "walks_side_by_side.py")
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
        return module
    finally:
        sys.path.remove(str(BENCHMARKS))


def _record(key: str, wall: float, **changes) -> dict:
    terrain, difficulty, seed, planner = key.split("-")
    record = {"key": key, "terrain": terrain, "difficulty": difficulty, "seed": int(seed), "planner": planner,
              "success": True, "missions": 3, "path_xy": [[0.0, 0.0], [0.25, 0.0]], "wall_time_s": wall,
              "planning_time_s": 0.4, "route_check_time_s": 2.0,
              "mission_records": [{"start": [0.0, 0.0, 0.0], "outcome": "walked", "sim_time_s": 4.0}]}
    record.update(changes)
    return record


def test_two_walks_are_the_same_but_for_their_timings_and_not_if_a_mission_differs():
    same_walk = _script().same_walk
    a = _record("stairs-hard-1000-capplanner", 40.0)
    assert same_walk(a, _record("stairs-hard-1000-capplanner", 31.0, planning_time_s=0.2, run_s=33.0))
    moved = _record("stairs-hard-1000-capplanner", 40.0, mission_records=[
        {"start": [0.0, 0.0, 0.0], "outcome": "walked", "sim_time_s": 4.05}])
    assert not same_walk(a, moved)
    assert not same_walk(a, _record("stairs-hard-1000-capplanner", 40.0, success=False))


def test_the_tasks_are_the_keys_asked_for_or_the_first_short_walks(tmp_path):
    tasks = _script()._tasks
    records = [_record("stairs-hard-1000-capplanner", 40.0), _record("obstacles-hard-1001-capplanner", 650.0),
               _record("both-medium-1000-capplanner", 31.0), _record("stairs-medium-1001-capplanner", 35.0)]
    (tmp_path / "results.jsonl").write_text("".join(json.dumps(r) + "\n" for r in records))
    assert tasks(tmp_path, [], 2) == [("stairs", "hard", 1000, "capplanner"), ("both", "medium", 1000, "capplanner")]
    assert tasks(tmp_path, ["obstacles-hard-1001-capplanner"], 2) == [("obstacles", "hard", 1001, "capplanner")]
    with pytest.raises(SystemExit, match="obstacles-hard-1999-capplanner"):
        tasks(tmp_path, ["obstacles-hard-1999-capplanner"], 2)


def test_a_new_setting_is_read_as_an_experiment_field_of_its_type_and_a_wrong_field_is_named():
    parse = _script().parse_settings
    assert parse(["control_mode=position", "time_step=0.004", "route_check=2", "record_missions=true"]) == {
        "control_mode": "position", "time_step": 0.004, "route_check": 2, "record_missions": True}
    assert parse([]) == {}
    with pytest.raises(SystemExit, match="'drive=position'"):
        parse(["drive=position"])
    with pytest.raises(SystemExit, match="'time_step'"):
        parse(["time_step"])
