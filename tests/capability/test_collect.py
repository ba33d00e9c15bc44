"""The capability collection: the same dataset from 1 or 2 local workers and from a Ray
cluster, resumable, surviving a worker killed in the middle of a trial, refusing a stale
manifest; the CLI's bad input."""

import json
import os
import secrets
import shutil
import socket
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from qz_drake.capability.collect import CRASH_ENV, LocalPool, collect, recertify
from qz_drake.capability.dataset import differing_fields, load_records, load_training_arrays
from qz_drake.capability.scenes import scene_recipe
from qz_drake.capability.trials import TIME_FIELDS, trial_index
from qz_drake.errors import ConfigError, QzError

# Seed 35's scene 0 is flat ground (both starts valid); turns in two topologies are the
# cheapest trials.
SMALL = dict(seed=35, scenes=1, topologies=("nominal", "front_bend"), kinds=("turn",), progress=False)
QZ = [sys.executable, "-m", "qz_drake.cli"]


def _same(a: Path, b: Path) -> None:
    ra, _ = load_records(a)
    rb, _ = load_records(b)
    assert differing_fields(ra, rb, skip=TIME_FIELDS) == []


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    assert scene_recipe(SMALL["seed"], 0)[0] == "flat"
    out = tmp_path_factory.mktemp("cap") / "one_worker"
    summary = collect(out, workers=1, **SMALL)
    assert summary.ran == 2 and summary.errors == 0
    return out


def test_a_collection_records_labels_and_network_inputs(reference):
    arrays, manifest = load_training_arrays(reference)
    assert len(arrays["index"]) == 2
    assert arrays["patch"].shape == (2, 20, 20) and arrays["feet"].shape == (2, 6, 3)
    assert set(arrays["topology"]) == {"nominal", "front_bend"}
    assert np.all(arrays["direction"] >= 0)  # turns carry their direction d
    assert list(arrays["index"]) == sorted(trial_index(0, 0, t, "turn", 1) for t in ("nominal", "front_bend"))
    assert set(manifest["fingerprints"]) == {"robot", "blc", "controller", "verdict", "scenes"}
    # Every failure has a reason code, every success none.
    records, _ = load_records(reference)
    assert all((r == "") == s for r, s in zip(records["reason"], records["success"]))


def test_two_workers_resume_and_a_killed_worker_give_the_same_dataset(reference, tmp_path):
    collect(tmp_path / "two", workers=2, **SMALL)
    _same(reference, tmp_path / "two")
    first = collect(tmp_path / "resumed", workers=1, limit=1, command="qz first", **SMALL)
    second = collect(tmp_path / "resumed", workers=1, command="qz second", **SMALL)
    assert (first.ran, second.already_done, second.ran) == (1, 1, 1)
    _same(reference, tmp_path / "resumed")
    assert json.loads((tmp_path / "resumed" / "manifest.json").read_text())["commands"] == ["qz first", "qz second"]
    victim = trial_index(0, 0, "front_bend", "turn", 1)
    os.environ[CRASH_ENV] = f"{victim}:{tmp_path / 'crashed_once'}"
    try:
        crashed = collect(tmp_path / "crash", workers=2, **SMALL)
    finally:
        del os.environ[CRASH_ENV]
    assert (tmp_path / "crashed_once").exists() and crashed.retries == 1 and crashed.errors == 0
    _same(reference, tmp_path / "crash")


def test_a_worker_is_replaced_by_a_fresh_process_after_max_tasks_and_no_record_is_lost():
    """Drake never frees a diagram with Python LeafSystems in the process that built it, so a
    long run's workers are recycled: with max_tasks 2, five specs on one worker run in three
    processes, every record arrives in order, and a bad max_tasks names the field."""
    pool = LocalPool(1, 0, 0, function=max, max_tasks=2)
    records, pids = [], []
    try:
        pool.run([3, -1, 5, 7, 2], lambda r: (records.append(r), pids.append(pool._workers[0]["process"].pid)))
    finally:
        pool.close()
    assert records == [3, 0, 5, 7, 2]
    assert pool.recycled == 2 and len(set(pids)) == 3
    with pytest.raises(QzError, match="max_tasks = 0"):
        LocalPool(1, 0, 0, function=max, max_tasks=0)


@pytest.mark.skipif(not Path("/proc/self/status").is_file(), reason="a process's memory is read from /proc (Linux)")
def test_a_worker_holding_more_than_max_memory_is_replaced_and_no_record_is_lost():
    """A Fig. 9 walk leaves a few hundred MB in its worker, so a worker is also replaced once it
    holds max_memory_mb after a record: with a limit below any Python process's, every record
    but the last is followed by a fresh worker; the memory read is the worker's own."""
    from qz_drake.capability.collect import resident_memory_mb

    assert resident_memory_mb(os.getpid()) > 1.0
    assert resident_memory_mb(2 ** 22 + 12345) is None  # no such process
    pool = LocalPool(1, 0, 0, function=max, max_memory_mb=1.0)
    records, pids = [], []
    try:
        pool.run([3, -1, 5], lambda r: (records.append(r), pids.append(pool._workers[0]["process"].pid)))
    finally:
        pool.close()
    assert records == [3, 0, 5]
    assert pool.recycled == 2 and len(set(pids)) == 3 and pool.peak_memory_mb > 1.0
    for bad in (0, -5, True, "3 GB"):
        with pytest.raises(QzError, match="max_memory_mb"):
            LocalPool(1, 0, 0, function=max, max_memory_mb=bad)


def test_a_stale_manifest_is_refused_naming_the_field(reference, tmp_path):
    copy = tmp_path / "stale"
    shutil.copytree(reference, copy)
    manifest = json.loads((copy / "manifest.json").read_text())
    manifest["fingerprints"]["blc"] = "0123456789abcdef"
    (copy / "manifest.json").write_text(json.dumps(manifest))
    with pytest.raises(ConfigError, match="fingerprints.blc"):
        collect(copy, workers=1, **SMALL)
    with pytest.raises(ConfigError, match="seed"):
        collect(reference, workers=1, **{**SMALL, "seed": 28})


def test_recertify_moves_a_dataset_to_code_that_reproduces_it_and_refuses_one_that_does_not(reference, tmp_path):
    # A code change that keeps behaviour (here: only the manifest's fingerprint differs)
    # is certified by re-running trials; the dataset then resumes under the new code.
    same = tmp_path / "refactored"
    shutil.copytree(reference, same)
    manifest = json.loads((same / "manifest.json").read_text())
    current = dict(manifest["fingerprints"])
    manifest["fingerprints"]["verdict"] = "0123456789abcdef"
    (same / "manifest.json").write_text(json.dumps(manifest))
    result = recertify(same, sample=2)
    assert result.changed == ["verdict"] and result.rerun == 2 and result.identical
    after = json.loads((same / "manifest.json").read_text())
    assert after["fingerprints"] == current
    assert after["certifications"][-1]["fingerprints_before"]["verdict"] == "0123456789abcdef"
    assert collect(same, workers=1, **SMALL).ran == 0  # accepted again, nothing left to run

    # Behaviour that changed (a stored outcome no longer reproduced) is refused: exit 1, the
    # differing field named, the manifest left as it was.
    changed, manifest, _ = _altered_copy(reference, tmp_path / "changed", {"blc": "0123456789abcdef"},
                                         "final_yaw_error_deg", 1.0)
    run = subprocess.run(QZ + ["capability", "recertify", str(changed), "--sample", "2"],
                         capture_output=True, text=True, timeout=300)
    assert run.returncode == 1, run.stderr
    assert "final_yaw_error_deg" in run.stdout and "2 of 2" in run.stdout
    assert json.loads((changed / "manifest.json").read_text()) == manifest


def test_collecting_into_a_complete_dataset_changes_no_file(reference, tmp_path):
    # data/capability is tracked: `qz capability collect` with nothing left to run must leave
    # its manifest (and every shard) as they are, not append its command line to the manifest.
    complete = tmp_path / "complete"
    shutil.copytree(reference, complete)
    before = {p.name: (p.read_bytes(), p.stat().st_mtime_ns) for p in complete.iterdir() if p.name != "collect.lock"}
    run = subprocess.run(QZ + ["capability", "collect", "--out", str(complete), "--seed", str(SMALL["seed"]),
                               "--scenes", "1",
                               "--topologies", "nominal,front_bend", "--kinds", "turn", "--json"],
                         capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr
    summary = json.loads(run.stdout)
    assert (summary["already_done"], summary["ran"]) == (2, 0)
    after = {p.name: (p.read_bytes(), p.stat().st_mtime_ns) for p in complete.iterdir() if p.name != "collect.lock"}
    assert after == before


@pytest.mark.parametrize("args, field", [
    (["--topologies", "sideways"], "--topologies"),
    (["--kinds", "jump"], "--kinds"),
    (["--scenes", "0"], "--scenes"),
    (["--ray-address", "127.0.0.1:9"], "--ray-address"),
    (["--log-every", "-1"], "--log-every"),
    (["--control-mode", "servo"], "trials.control_mode"),
    (["--control-mode", "torque", "--time-step", "0.004"], "trials.time_step"),  # the explicit PD past 2 ms
])
def test_bad_collect_input_is_one_line_exit_2(tmp_path, args, field):
    run = subprocess.run(QZ + ["capability", "collect", "--out", str(tmp_path / "d"), "--scenes", "1"] + args,
                         capture_output=True, text=True, timeout=180)
    assert run.returncode == 2, run.stderr
    lines = run.stderr.strip().splitlines()
    assert len(lines) == 1 and field in lines[0], run.stderr


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.mark.slow
def test_a_local_ray_cluster_gives_the_same_dataset_and_survives_a_killed_worker(reference, tmp_path,
                                                                                  monkeypatch):
    ray_bin = Path(sys.executable).with_name("ray")
    port = _free_port()
    # A head on loopback only (Ray's own switch: without it the node takes the machine's outward
    # address whatever --node-ip-address says), with its own token for Ray's token auth.
    token = {"RAY_AUTH_MODE": "token", "RAY_AUTH_TOKEN": secrets.token_hex(16)}
    env = {**os.environ, "RAY_USAGE_STATS_ENABLED": "0", "RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER": "0", **token}
    subprocess.run([str(ray_bin), "start", "--head", "--node-ip-address=127.0.0.1", f"--port={port}",
                    "--num-cpus=2", "--include-dashboard=false", "--disable-usage-stats"],
                   check=True, capture_output=True, env=env, timeout=180)
    address = f"127.0.0.1:{port}"
    for name, value in token.items():
        monkeypatch.setenv(name, value)
    try:
        collect(tmp_path / "ray", ray_address=address, **SMALL)
        _same(reference, tmp_path / "ray")
        victim = trial_index(0, 0, "nominal", "turn", 1)
        os.environ[CRASH_ENV] = f"{victim}:{tmp_path / 'ray_crashed_once'}"
        try:
            collect(tmp_path / "ray_crash", ray_address=address, **SMALL)
        finally:
            del os.environ[CRASH_ENV]
        assert (tmp_path / "ray_crashed_once").exists()
        _same(reference, tmp_path / "ray_crash")
    finally:
        subprocess.run([str(ray_bin), "stop", "--force"], capture_output=True, env=env, timeout=120)


def test_the_fingerprint_covers_the_code_a_trial_runs():
    from qz_drake.capability.dataset import fingerprinted_modules

    modules = fingerprinted_modules()
    # Found by following imports from run_trial: the defaults of the scenario (time step,
    # contact), the walk and its metrics, the heightmap's interpolation, the BLC's verdict.
    for name in ("qz_drake.config", "qz_drake.simulation", "qz_drake.terrain.heightmap",
                 "qz_drake.station", "qz_drake.systems.ik_tracker"):
        assert name in modules["controller"], name
    assert "qz_drake.trajopt.verdict" in modules["blc"] and modules["verdict"] == ["qz_drake.verdict"]
    assert "qz_drake.capability.trials" in modules["scenes"]
    everything = [m for names in modules.values() for m in names]
    assert len(everything) == len(set(everything))
    assert not any(m.startswith(("qz_drake.viz", "qz_drake.cli", "qz_drake.planning")) for m in everything)


def test_the_robot_code_hashes_kept_between_processes_are_those_of_the_sources(tmp_path, monkeypatch):
    """A model's load checks the robot fingerprint; the modules' hashes it takes are kept in a
    file under the hash of the sources and used only for the same sources."""
    from qz_drake.capability import dataset

    computed = [f"{m}:{dataset._code_hash(m)}" for m in dataset.fingerprinted_modules()["robot"]]
    cache = tmp_path / "__pycache__" / "robot_code_hashes.json"
    monkeypatch.setattr(dataset, "_ROBOT_HASHES_CACHE", cache)
    assert dataset._robot_code_hashes() == computed
    kept = json.loads(cache.read_text())
    assert kept["hashes"] == computed and [p.name for p in cache.parent.iterdir()] == [cache.name]
    cache.write_text(json.dumps({"sources": kept["sources"], "hashes": ["kept"]}))
    assert dataset._robot_code_hashes() == ["kept"]
    for stale in (json.dumps({"sources": "other sources", "hashes": ["kept"]}), "not json", "[]"):
        cache.write_text(stale)
        assert dataset._robot_code_hashes() == computed
    # A folder that cannot be written (here a file stands where it would be): computed each time.
    blocked = tmp_path / "a_file"
    blocked.write_text("")
    monkeypatch.setattr(dataset, "_ROBOT_HASHES_CACHE", blocked / "robot_code_hashes.json")
    assert dataset._robot_code_hashes() == computed


def test_a_folder_being_collected_into_is_locked_against_a_second_writer(reference, tmp_path):
    from qz_drake.capability.dataset import DatasetLock

    copy = tmp_path / "busy"
    shutil.copytree(reference, copy)
    lock = DatasetLock(copy)  # as a running collection holds it
    try:
        with pytest.raises(ConfigError, match="collect.lock"):
            collect(copy, workers=1, **SMALL)
        with pytest.raises(ConfigError, match="dataset.*collect.lock"):
            recertify(copy, sample=1)
    finally:
        lock.release()
    assert collect(copy, workers=1, **SMALL).ran == 0  # free again once the writer is gone


def test_a_background_collection_logs_plain_progress_lines(tmp_path, capsys):
    collect(tmp_path / "logged", workers=1, limit=1, log_every=1e-6, **SMALL)
    lines = [line for line in capsys.readouterr().err.splitlines() if line.startswith("trials ")]
    assert lines and lines[-1].startswith("trials 1/1 (100.0 %)") and "ETA" in lines[-1]


def test_relative_imports_resolve_against_the_importing_package():
    import ast

    from qz_drake.capability.dataset import _imported_modules

    tree = ast.parse("from . import a\nfrom ..x import y\nimport qz_drake.z\nimport numpy")
    assert _imported_modules("qz_drake.pkg.mod", tree) == {
        "qz_drake.pkg", "qz_drake.pkg.a", "qz_drake.x", "qz_drake.x.y", "qz_drake.z"}
    assert _imported_modules("qz_drake.pkg", tree, is_package=True) == {
        "qz_drake.pkg", "qz_drake.pkg.a", "qz_drake.x", "qz_drake.x.y", "qz_drake.z"}


def test_imports_are_found_at_any_depth_of_the_code():
    """The fingerprint's import scan visits statements only; it finds every import a full walk
    of the syntax tree finds: in functions, classes, branches, handlers, loops, with blocks
    and match cases, here and in every module of the package."""
    import ast

    from qz_drake.capability.dataset import _PACKAGE_ROOT, _imported_modules

    tree = ast.parse(
        "def f():\n    class C:\n        def g(self):\n            import qz_drake.a\n"
        "try:\n    pass\nexcept ImportError:\n    from qz_drake import b\nelse:\n    import qz_drake.c\n"
        "finally:\n    import qz_drake.d\n"
        "for _ in ():\n    pass\nelse:\n    import qz_drake.e\n"
        "with open('x'):\n    import qz_drake.f\n"
        "match 1:\n    case 1:\n        import qz_drake.g\n")
    assert _imported_modules("qz_drake.m", tree) == {"qz_drake", "qz_drake.b", *(f"qz_drake.{c}" for c in "acdefg")}
    for file in _PACKAGE_ROOT.rglob("*.py"):
        tree = ast.parse(file.read_text())
        # Every import the full walk finds, put at the top level of a module of its own.
        walked = ast.Module([n for n in ast.walk(tree) if isinstance(n, (ast.Import, ast.ImportFrom))], [])
        assert _imported_modules("qz_drake.m", tree) == _imported_modules("qz_drake.m", walked), file


def test_recertification_compares_labels_exactly_and_measurements_to_a_tolerance():
    """Across processors the same code reproduces labels but not the last bits of measured
    floats (1e-10 apart, seen between two machines): recertification accepts that, not a
    changed label or a measurement that moved."""
    from qz_drake.capability.collect import RECERTIFY_ATOL, RECERTIFY_RTOL

    stored = {"success": np.array([True]), "reason": np.array([""]),
              "blc_iterations": np.array([8]), "final_xy_error_m": np.array([0.0078108275326827])}
    noisy = dict(stored, final_xy_error_m=np.array([0.0078108275323259]))
    tol = dict(rtol=RECERTIFY_RTOL, atol=RECERTIFY_ATOL)
    assert differing_fields(stored, noisy) == ["final_xy_error_m"]  # bit for bit: differs
    assert differing_fields(stored, noisy, **tol) == []
    moved = dict(stored, final_xy_error_m=np.array([0.0091]))
    assert differing_fields(stored, moved, **tol) == ["final_xy_error_m"]
    flipped = dict(noisy, success=np.array([False]), blc_iterations=np.array([9]))
    assert differing_fields(stored, flipped, **tol) == ["success", "blc_iterations"]
    # A failed walk's measurements are not compared (where it was stopped moves with rounding),
    # its label and the network inputs always are.
    from qz_drake.capability.collect import MEASURED_FIELDS
    from qz_drake.capability.trials import ARRAY_FIELDS, RECORD_FIELDS

    assert set(MEASURED_FIELDS) <= set(RECORD_FIELDS)
    assert not set(MEASURED_FIELDS) & {"status", "success", "reason", "blc_success", "blc_iterations",
                                       "kind", "topology", "heading", *ARRAY_FIELDS}


def _altered_copy(reference, dest: Path, fingerprints: dict, field: str, delta: float):
    """A copy of a dataset whose manifest names other code (``fingerprints`` updated) and whose
    first shard's ``field`` is off by ``delta``: (folder, manifest, the shard's arrays)."""
    shutil.copytree(reference, dest)
    manifest = json.loads((dest / "manifest.json").read_text())
    manifest["fingerprints"].update(fingerprints)
    (dest / "manifest.json").write_text(json.dumps(manifest))
    shard = dest / manifest["shards"][0]["file"]
    with np.load(shard) as stored:
        arrays = {k: stored[k] for k in stored.files}
    arrays[field] = arrays[field] + delta
    np.savez_compressed(shard, **arrays)
    return dest, manifest, arrays


@pytest.mark.slow  # a second interpreter on a second source tree: 13 s of make test's budget
def test_recertify_with_the_certified_code_tells_a_machines_difference_from_the_changes(reference, tmp_path,
                                                                                         certified_code):
    # The certified code: a copy of this tree whose verdict module differs in syntax, not in
    # behaviour, so that the running code is "a change" against the manifest.
    certified, fingerprints_of = certified_code
    settings = json.loads((reference / "manifest.json").read_text())["settings"]
    # Records as another processor might have stored them: an iteration count the code gives
    # on neither side here.
    data, manifest, arrays = _altered_copy(reference, tmp_path / "collected_elsewhere",
                                           fingerprints_of(settings), "blc_iterations", 1)

    refused = recertify(data, sample=2)
    assert not refused.identical and len(refused.mismatches) == 2
    assert json.loads((data / "manifest.json").read_text()) == manifest

    # With the certified code re-run here, the same difference: the machine's, accepted and listed.
    result = recertify(data, sample=2, reference_code=certified)
    assert result.identical and result.changed == ["verdict"] and len(result.machine_differences) == 2
    after = json.loads((data / "manifest.json").read_text())
    assert [m["index"] for m in after["certifications"][-1]["machine_differences"]] == sorted(arrays["index"])

    # A tree that is not the certified code is refused, naming the option.
    made_up, _, _ = _altered_copy(reference, tmp_path / "made_up", {"verdict": "0123456789abcdef"},
                                  "blc_iterations", 1)
    with pytest.raises(ConfigError, match="--reference-code"):
        recertify(made_up, sample=1, reference_code=certified)


@pytest.mark.slow  # a collection, then a second interpreter on a second source tree
def test_the_certified_code_reruns_a_dataset_from_before_the_drive_fields_as_it_was_labelled(tmp_path,
                                                                                              certified_code):
    # A manifest that names neither the drives nor the step (every dataset before issue 53's
    # defaults) was labelled with the controller's PD at 2 ms: the certified code, whose own
    # defaults are the drives' PD, is handed those settings, not left to its defaults.
    from qz_drake.capability.trials import TrialConfig

    certified, fingerprints_of = certified_code
    out = tmp_path / "torque"
    assert collect(out, workers=1, config=TrialConfig(control_mode="torque", time_step=0.002), **SMALL).ran == 2
    manifest = json.loads((out / "manifest.json").read_text())
    settings = dict(manifest["settings"])
    for key in ("control_mode", "time_step", "blc_ladder", "blc_terminal_stance"):
        del manifest["settings"][key]
    (out / "manifest.json").write_text(json.dumps(manifest))
    data, _, _ = _altered_copy(out, tmp_path / "collected_elsewhere", fingerprints_of(settings), "blc_iterations", 1)
    result = recertify(data, sample=2, reference_code=certified)
    assert result.identical and result.changed == ["verdict"] and len(result.machine_differences) == 2


def test_a_text_longer_than_its_field_is_refused_not_cut():
    """numpy would cut a scene kind longer than its field silently (the first episode
    collection stored stairs_among_boxes as stairs_among_box): records_to_arrays refuses it."""
    from qz_drake.capability.dataset import records_to_arrays
    from qz_drake.capability.trials import RECORD_FIELDS, blank_record

    fine = dict(blank_record(), scene_kind="stairs_among_boxes")
    assert records_to_arrays([fine])["scene_kind"][0] == "stairs_among_boxes"
    width = int(RECORD_FIELDS["topology"][1:])
    with pytest.raises(ConfigError, match=r"record.topology.*longer than its field"):
        records_to_arrays([dict(blank_record(), topology="x" * (width + 1))])


def test_a_local_ray_address_is_one_the_command_starts_and_a_bad_one_is_named():
    from qz_drake.capability.collect import LOCAL_RAY, check_ray_address
    from qz_drake.errors import QzError

    check_ray_address(LOCAL_RAY)  # nothing to reach: the run starts it
    for bad in ("localhost", "127.0.0.1:", ":8265"):
        with pytest.raises(QzError, match="--ray-address"):
            check_ray_address(bad)


def test_a_uniform_episode_sample_is_distinct_whole_episodes_in_mission_order_and_fixed_by_its_key():
    """benchmarks/trial_drives.py --uniform: episodes drawn as the dataset has them (no crashed
    one), each with all its records in mission order; the same key draws the same episodes."""
    import numpy as np

    from qz_drake.capability.collect import _episode_sample

    # Five episodes of 1-3 missions, their records out of order; episode 3 crashed.
    index = np.array([2, 0, 1, 1, 0, 3, 4, 2, 2])
    heading = np.array([1, 0, 0, 1, 1, 0, 0, 0, 2])
    status = np.array(["executed"] * 5 + ["error"] + ["executed"] * 3)
    arrays = {"index": index, "heading_sample": heading, "status": status, "scene": index * 10,
              "topology": np.array(["nominal"] * 9), "kind": np.array(["forward"] * 9),
              "success": np.ones(9, bool), "reason": np.array([""] * 9), "scene_kind": np.array(["stairs"] * 9)}
    specs, stored = _episode_sample(arrays, 3, "key", 7, uniform=True)
    chosen = [s.index for s in specs]
    assert len(set(chosen)) == 3 and 3 not in chosen and set(chosen) <= {0, 1, 2, 4}
    for s in specs:
        assert s.scene == 10 * s.index
        assert [int(r["heading_sample"][0]) for r in stored[s.index]] == sorted(heading[index == s.index].tolist())
    assert [s.index for s in _episode_sample(arrays, 3, "key", 7, uniform=True)[0]] == chosen
    assert len(_episode_sample(arrays, 10, "key", 7, uniform=True)[0]) == 4
