"""The capability dataset: append-only shards with a manifest (paper 000 II-E.1's samples).

A dataset folder holds ``manifest.json`` and ``shard-NNNNN.npz`` files (compressed, no
pickle). Each shard is a batch of finished trial records, written by the collection's driver
only, atomically (a temporary file renamed), and the manifest is rewritten after each shard
(and only then: resuming a complete dataset changes no file).
A trial's index is derived from (seed, index), so a resumed collection skips exactly the
trials some shard holds: a trial is never run twice into the dataset, and an interrupted one
is simply run again.

The manifest records what produced the labels: the collection's settings and a fingerprint of
each component (robot, BLC, controller, verdict, scenes), each a hash of its configuration and
of its code's syntax tree (comments and docstrings do not count). A folder whose fingerprints
differ from the running code's is refused with the differing field named: the capability
learned is that of one BLC-robot system, never a mix.
"""

from __future__ import annotations

import ast
import dataclasses
import functools
import hashlib
import json
import os
import sys
import tempfile
from pathlib import Path

import numpy as np

from qz_drake.capability.patches import PATCH_SIZE
from qz_drake.errors import ConfigError, bad_value

# The arrays of the dataset contract (load_training_arrays) that the networks learn from.
REQUIRED_KEYS = ("patch", "feet", "direction", "success", "blc_success", "scene", "topology", "kind")
# The fields of the learners' arrays (load_training_arrays, load_plan_arrays).
LEARNER_FIELDS = ("patch", "feet", "direction", "success", "blc_success", "scene", "scene_kind",
                  "topology", "kind", "index", "reason", "difficulty")
# Protocols whose specs are chains of missions, a record per mission (collect.PROTOCOLS, and
# "routes": the episodes of the planners' own routes, qz_drake.experiments.route_episodes).
CHAINED_PROTOCOLS = ("episodes", "plans", "routes")
# Settings that say where a dataset came from, not how its trials run (TrialConfig's are the
# rest): a relabelled dataset's source (capability/relabel.py).
PROVENANCE_SETTINGS = ("relabelled_from",)
FORMAT = "qz_drake.capability.dataset/1"
MANIFEST = "manifest.json"

# Where the fingerprinted code starts: every qz_drake module these import, directly or not,
# at module level or inside a function (found in their syntax trees, so the set is the same
# whatever the process has imported), is part of the fingerprint, except the packages below,
# which a trial never runs: recordings and plots, the command line and benchmarks, the LCM
# station backend, the collection driver (it only schedules run_trial), and the CapPlanner
# stack (the learned model and the planners that use it, reachable from qz_drake.simulation's
# capplanner controller only). A new module is fingerprinted unless it falls under one of
# these. Each module belongs to the first component whose prefix it matches.
FINGERPRINT_ROOTS = ("qz_drake.capability.trials", "qz_drake.capability.episodes",
                     "qz_drake.capability.plan_chains", "qz_drake.simulation",
                     "qz_drake.systems.blc", "qz_drake.systems.blc_plan")
UNFINGERPRINTED = ("qz_drake.viz", "qz_drake.cli", "qz_drake.bench", "qz_drake.hardware",
                   "qz_drake.planning",
                   "qz_drake.capability.collect", "qz_drake.capability.stats",
                   "qz_drake.capability.model", "qz_drake.capability.model_base",
                   "qz_drake.capability.boosted", "qz_drake.capability.model_commands",
                   "qz_drake.capability.networks", "qz_drake.capability.training",
                   "qz_drake.capability.evaluation", "qz_drake.capability.plots",
                   "qz_drake.capability.dataset")
_COMPONENT_PREFIXES = (
    ("robot", ("qz_drake.robot",)),
    ("blc", ("qz_drake.trajopt", "qz_drake.systems.blc", "qz_drake.systems.blc_plan")),
    ("verdict", ("qz_drake.verdict",)),
    ("scenes", ("qz_drake.capability",)),
    ("controller", ("qz_drake",)),  # the station, systems, simulation, terrain, config, ...
)


_PACKAGE_ROOT = Path(__file__).resolve().parents[1]  # the qz_drake folder


@functools.cache
def _module_file(name: str) -> Path | None:
    """The source file of a qz_drake module, found in the package's folder (not by importing
    it: importlib's find_spec imports every parent package, which made a model's robot check
    take a second); None for a name that is no module (a class or function imported by name)."""
    parts = name.split(".")
    if parts[0] != "qz_drake":
        return None
    base = _PACKAGE_ROOT.joinpath(*parts[1:])
    for file in (base.with_suffix(".py"), base / "__init__.py"):
        if file.is_file():
            return file
    return None


def _statements(tree: ast.AST):
    """Every statement of a syntax tree, at any depth (in functions, classes, branches, handlers
    and match cases); expressions are not entered. An import is a statement, so this finds what
    ast.walk finds in a tenth of the nodes (the model's robot check walks the code it loads)."""
    stack = [tree]
    while stack:
        node = stack.pop()
        if isinstance(node, ast.stmt):
            yield node
        for field in ("body", "orelse", "finalbody", "handlers", "cases"):
            children = getattr(node, field, None)
            if isinstance(children, list):
                stack.extend(children)


def _imported_modules(name: str, tree: ast.AST, is_package: bool = False) -> set[str]:
    """qz_drake modules a module's code imports (anywhere in it); relative imports resolve
    against the module's package (the module itself for a package's __init__)."""
    found = set()
    package = name if is_package else name.rpartition(".")[0]
    for node in _statements(tree):
        if isinstance(node, ast.Import):
            found.update(a.name for a in node.names if a.name.startswith("qz_drake"))
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                base = ".".join(package.split(".")[: len(package.split(".")) - node.level + 1]
                                + ([node.module] if node.module else []))
            if base.startswith("qz_drake"):
                found.add(base)
                found.update(f"{base}.{a.name}" for a in node.names)  # kept if a module
    return found


def fingerprinted_modules() -> dict[str, list[str]]:
    """Component -> the modules of its fingerprint (the import closure of FINGERPRINT_ROOTS)."""
    seen, queue = set(), list(FINGERPRINT_ROOTS)
    while queue:
        name = queue.pop()
        if name in seen or any(name == u or name.startswith(u + ".") for u in UNFINGERPRINTED):
            continue
        file = _module_file(name)
        if file is None:
            continue
        seen.add(name)
        queue.extend(_imported_modules(name, ast.parse(file.read_text()), file.name == "__init__.py"))
        parent = name.rpartition(".")[0]
        if parent.startswith("qz_drake"):
            queue.append(parent)  # a package's __init__ runs before its modules
    out: dict[str, list[str]] = {component: [] for component, _ in _COMPONENT_PREFIXES}
    for name in sorted(seen):
        for component, prefixes in _COMPONENT_PREFIXES:
            if any(name == p or name.startswith(p + ".") for p in prefixes):
                out[component].append(name)
                break
    return out


def _code_hash(module_name: str) -> str:
    """Hash of a module's syntax tree without docstrings (comments are not in the tree)."""
    source = _module_file(module_name).read_text()
    tree = ast.parse(source)
    for node in ast.walk(tree):
        body = getattr(node, "body", None)
        if isinstance(body, list) and body and isinstance(body[0], ast.Expr) \
                and isinstance(getattr(body[0], "value", None), ast.Constant) \
                and isinstance(body[0].value.value, str):
            node.body = body[1:] or [ast.Pass()]
    return hashlib.sha256(ast.dump(tree).encode()).hexdigest()


def _digest(*parts) -> str:
    return hashlib.sha256("\n".join(str(p) for p in parts).encode()).hexdigest()[:16]


def fingerprints(trial_config, criteria=None) -> dict[str, str]:
    """The running code's fingerprint per component (and the trial settings' own)."""
    from qz_drake.config import SuccessCriteria
    from qz_drake.trajopt.parameters import BlcParameters

    config = {
        "robot": _robot_config(),
        "blc": (repr(BlcParameters()),),
        "controller": (repr((trial_config.speed, trial_config.phase_duration, trial_config.kp,
                             trial_config.kd, trial_config.settle_after, trial_config.control_mode,
                             trial_config.time_step)),),
        "verdict": (repr(criteria or SuccessCriteria()),),
        "scenes": (repr(trial_config),),
    }
    return {name: _digest(*config[name], *(f"{m}:{_code_hash(m)}" for m in modules))
            for name, modules in fingerprinted_modules().items()}


def _robot_config() -> tuple:
    from qz_drake.robot.params import DEFAULT_PARAMS
    from qz_drake.robot.urdf import make_urdf

    return repr(DEFAULT_PARAMS), make_urdf(DEFAULT_PARAMS)


@functools.cache
def robot_fingerprint() -> str:
    """The running code's robot fingerprint (fingerprints()["robot"]: no trial setting enters it);
    the code does not change while a process runs, so it is computed once."""
    return _digest(*_robot_config(), *_robot_code_hashes())


# Where _robot_code_hashes keeps its answer between processes, as Python keeps bytecode.
_ROBOT_HASHES_CACHE = Path(__file__).parent / "__pycache__" / "robot_code_hashes.json"


def _robot_code_hashes() -> list[str]:
    """``module:code hash`` of each module of the robot component. Finding them parses every
    fingerprinted module (56 files, a fifth of a second each time a model loads), so the answer
    is kept in _ROBOT_HASHES_CACHE under the hash of every qz_drake source file and the Python
    version (ast.dump's format): the same sources give the same answer, and any edit anywhere in
    the package recomputes it. A cache that cannot be read or written is passed by."""
    digest = hashlib.sha256(sys.version.encode())
    for file in sorted(_PACKAGE_ROOT.rglob("*.py")):
        digest.update(f"{file.relative_to(_PACKAGE_ROOT)}\n".encode())
        digest.update(hashlib.sha256(file.read_bytes()).digest())
    sources = digest.hexdigest()
    try:
        kept = json.loads(_ROBOT_HASHES_CACHE.read_text())
        if kept["sources"] == sources:
            return list(kept["hashes"])
    except (OSError, ValueError, KeyError, TypeError):
        pass
    hashes = [f"{m}:{_code_hash(m)}" for m in fingerprinted_modules()["robot"]]
    tmp = None
    try:
        _ROBOT_HASHES_CACHE.parent.mkdir(exist_ok=True)
        # A name of its own: processes loading models at once each write a whole file.
        with tempfile.NamedTemporaryFile("w", dir=_ROBOT_HASHES_CACHE.parent, suffix=".tmp", delete=False) as tmp:
            json.dump({"sources": sources, "hashes": hashes}, tmp)
        os.replace(tmp.name, _ROBOT_HASHES_CACHE)
    except OSError:
        if tmp is not None:
            Path(tmp.name).unlink(missing_ok=True)
    return hashes


def combined_fingerprint(parts: dict[str, str]) -> str:
    return _digest(*(f"{k}={parts[k]}" for k in sorted(parts)))


def _atomic_write(path: Path, write) -> None:
    tmp = path.with_name(path.name + ".tmp")
    write(tmp)
    os.replace(tmp, path)


LOCK = "collect.lock"


class DatasetLock:
    """An exclusive lock on a dataset folder (``collect.lock``, fcntl.flock), held by the one
    process that may write it: two collections into one folder would number their shards alike
    and overwrite each other. The operating system releases it when the process ends, however
    it ends, so a killed collection never leaves the folder locked."""

    def __init__(self, path, field: str = "--out"):
        import fcntl

        self.path = Path(path) / LOCK
        self._file = open(self.path, "a+")
        try:
            fcntl.flock(self._file, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            self._file.seek(0)
            holder = self._file.read().strip() or "another process"
            self._file.close()
            raise bad_value(field, str(Path(path)), f"is being written by {holder} (collect.lock); "
                                                    "wait for it to finish or stop it") from None
        self._file.seek(0)
        self._file.truncate()
        self._file.write(f"process {os.getpid()}\n")
        self._file.flush()

    def release(self) -> None:
        if not self._file.closed:
            self._file.close()  # closing the descriptor releases the flock


class TrialStore:
    """A dataset folder being collected into (one writer: the collection's driver, which holds
    the folder's DatasetLock until ``close``)."""

    def __init__(self, path, *, seed: int, settings: dict, parts: dict[str, str], command: str = ""):
        self.path = Path(path)
        if self.path.exists() and not self.path.is_dir():
            raise bad_value("--out", str(path), "is a file, not a dataset folder")
        self.path.mkdir(parents=True, exist_ok=True)
        self.lock = DatasetLock(self.path)
        try:
            self._open(seed, settings, parts, command)
        except BaseException:
            self.lock.release()
            raise

    def close(self) -> None:
        self.lock.release()

    def _open(self, seed: int, settings: dict, parts: dict[str, str], command: str) -> None:
        manifest_path = self.path / MANIFEST
        # The command is recorded with the first shard it adds: a resumed collection with nothing
        # left to run leaves an existing (perhaps tracked) manifest untouched.
        self._command = command
        if manifest_path.exists():
            self.manifest = read_manifest(self.path)
            check_same(with_settings_before_they_existed(self.manifest, settings), seed=seed, settings=settings,
                       parts=parts, where=str(self.path))
            return
        if any(self.path.glob("shard-*.npz")):
            raise bad_value("--out", str(self.path), "holds shards but no manifest.json")
        self.manifest = {"format": FORMAT, "seed": int(seed), "settings": settings,
                         "fingerprints": parts, "fingerprint": combined_fingerprint(parts),
                         "commands": [], "shards": []}
        self._record_command()
        self._write_manifest()

    def _record_command(self) -> None:
        if self._command:
            self.manifest.setdefault("commands", []).append(self._command)
            self._command = ""

    def note(self, key: str, value) -> None:
        """Keeps ``value`` under ``key`` in the manifest (what a relabelling checked, say)."""
        self.manifest[key] = value
        self._write_manifest()

    def done_indices(self) -> set[int]:
        done = set()
        for shard in self.manifest["shards"]:
            with np.load(self.path / shard["file"], allow_pickle=False) as data:
                done.update(int(i) for i in data["index"])
        return done

    def append(self, records: list[dict]) -> Path | None:
        """Writes a shard of finished records and lists it in the manifest."""
        if not records:
            return None
        number = len(self.manifest["shards"])
        name = f"shard-{number:05d}.npz"
        arrays = records_to_arrays(records)
        _atomic_write(self.path / name, lambda tmp: np.savez_compressed(open(tmp, "wb"), **arrays))
        self._record_command()
        self.manifest["shards"].append({
            "file": name, "count": len(records),
            "executed": int(np.count_nonzero(arrays["status"] == "executed")),
            "errors": int(np.count_nonzero(arrays["status"] == "error")),
            "invalid": int(np.count_nonzero(arrays["status"] == "invalid")),
            **({"blc_only": n} if (n := int(np.count_nonzero(arrays["status"] == "blc_only"))) else {}),
        })
        self._write_manifest()
        return self.path / name

    def _write_manifest(self) -> None:
        write_manifest(self.path, self.manifest)


def write_manifest(path, manifest: dict) -> None:
    """Writes a dataset folder's manifest atomically (a reader never sees half of it)."""
    text = json.dumps(manifest, indent=1)
    _atomic_write(Path(path) / MANIFEST, lambda tmp: tmp.write_text(text))


def read_manifest(path) -> dict:
    path = Path(path)
    file = path / MANIFEST
    if not file.is_file():
        raise bad_value("dataset", str(path), "no manifest.json: not a capability dataset")
    try:
        manifest = json.loads(file.read_text())
    except json.JSONDecodeError as e:
        raise bad_value("dataset", str(file), f"manifest is not JSON ({e})") from None
    if manifest.get("format") != FORMAT:
        raise bad_value("dataset.format", manifest.get("format"), f"expected {FORMAT}")
    return manifest


def with_settings_before_they_existed(manifest: dict, settings: dict) -> dict:
    """``manifest`` with the trial settings its collection did not know yet (a field of
    ``settings`` its own do not name) as they were then (trials.SETTINGS_BEFORE_THEY_EXISTED),
    so that a dataset collected before a field existed compares with a collection asking for
    those values, and differs from one asking for others by that field."""
    from qz_drake.capability.trials import SETTINGS_BEFORE_THEY_EXISTED

    stored = dict(manifest.get("settings", {}))
    for key, value in SETTINGS_BEFORE_THEY_EXISTED.items():
        if key in settings:
            stored.setdefault(key, value)
    return dict(manifest, settings=stored)


def check_same(manifest: dict, *, seed=None, settings=None, parts=None, where: str = "dataset") -> None:
    """Raises ConfigError naming the first field where a dataset differs from what is asked."""
    if seed is not None and manifest.get("seed") != seed:
        raise ConfigError(f"{where}: seed = {manifest.get('seed')} in the dataset, {seed} asked: "
                          "a folder holds one collection")
    if settings is not None:
        for key in sorted(set(settings) | set(manifest.get("settings", {}))):
            if manifest.get("settings", {}).get(key) != settings.get(key):
                raise ConfigError(f"{where}: settings.{key} = {manifest.get('settings', {}).get(key)!r} "
                                  f"in the dataset, {settings.get(key)!r} now")
    if parts is not None:
        for key in sorted(set(parts) | set(manifest.get("fingerprints", {}))):
            if manifest.get("fingerprints", {}).get(key) != parts.get(key):
                raise ConfigError(
                    f"{where}: fingerprints.{key} = {manifest.get('fingerprints', {}).get(key)} in the "
                    f"dataset, {parts.get(key)} in this code: the labels describe another {key}")


def check_arrays(arrays: dict) -> int:
    """Checks the keys and shapes of the dataset contract; returns the number of rows."""
    for key in REQUIRED_KEYS:
        if key not in arrays:
            raise bad_value("dataset.arrays", sorted(arrays), f"missing the {key!r} array")
    n = len(arrays["success"])
    shapes = {"patch": (n, PATCH_SIZE, PATCH_SIZE), "feet": (n, 6, 3)}
    for key in REQUIRED_KEYS:
        expected = shapes.get(key, (n,))
        if np.shape(arrays[key]) != expected:
            raise bad_value(f"dataset.{key}", f"array of shape {np.shape(arrays[key])}", f"expected {expected}")
    for key in ("patch", "feet"):
        if not np.isfinite(arrays[key]).all():
            raise bad_value(f"dataset.{key}", "non-finite values", "every trial's inputs must be finite")
    return n


def records_to_arrays(records: list[dict]) -> dict[str, np.ndarray]:
    from qz_drake.capability.trials import ARRAY_FIELDS, RECORD_FIELDS, TIME_FIELDS

    out = {name: np.array([r[name] for r in records], dtype=dt) for name, dt in RECORD_FIELDS.items()}
    for name, dt in RECORD_FIELDS.items():
        # A text longer than its field would be cut silently by numpy: refuse it instead (the
        # free-text fields are cut on purpose, with their length, where they are written).
        if dt.startswith("U"):
            long = [str(r[name]) for r in records if len(str(r[name])) > int(dt[1:])]
            if long:
                raise bad_value(f"record.{name}", long[0], f"longer than its field ({dt}): widen it in "
                                                            "qz_drake.capability.trials.RECORD_FIELDS")
    for name, (shape, dt) in ARRAY_FIELDS.items():
        out[name] = np.array([np.asarray(r[name]).reshape(shape) for r in records], dtype=dt)
    for name in TIME_FIELDS:
        out[name] = np.array([r[name] for r in records], dtype="f8")
    return out


def differing_fields(a: dict, b: dict, skip=(), rtol: float = 0.0, atol: float = 0.0) -> list[str]:
    """The fields where two sets of record arrays differ (NaN equals NaN), in a's order; with
    a tolerance, floating-point fields count as equal within it (np.isclose) and every other
    field must still be equal."""
    out = []
    for key in a:
        if key in skip:
            continue
        if key not in b:
            out.append(key)
            continue
        x, y = np.asarray(a[key]), np.asarray(b[key])
        nan_aware = x.dtype.kind in "fc" and y.dtype.kind in "fc"
        if x.shape != y.shape:
            out.append(key)
        elif nan_aware and (rtol > 0 or atol > 0):
            if not np.all(np.isclose(x, y, rtol=rtol, atol=atol, equal_nan=True)):
                out.append(key)
        elif not np.array_equal(x, y, equal_nan=nan_aware):
            out.append(key)
    return out + [key for key in b if key not in a and key not in skip]


def load_records(path) -> tuple[dict[str, np.ndarray], dict]:
    """Every record of a dataset (executed and errors), sorted by trial index, and the
    manifest. Raises ConfigError when an index appears twice (a corrupted folder)."""
    path = Path(path)
    manifest = read_manifest(path)
    parts = []
    for shard in manifest["shards"]:
        file = path / shard["file"]
        if not file.is_file():
            raise bad_value("dataset", str(path), f"{shard['file']} is listed but missing")
        with np.load(file, allow_pickle=False) as data:
            parts.append({k: data[k] for k in data.files})
    if not parts:
        from qz_drake.capability.trials import ARRAY_FIELDS, RECORD_FIELDS, TIME_FIELDS
        empty = {k: np.zeros(0, dtype=dt) for k, dt in RECORD_FIELDS.items()}
        empty.update({k: np.zeros((0, *s), dtype=dt) for k, (s, dt) in ARRAY_FIELDS.items()})
        empty.update({k: np.zeros(0) for k in TIME_FIELDS})
        return empty, manifest
    arrays = {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}
    # An episode (protocol "episodes") or a plan chain ("plans") stores a record per mission:
    # index, then the mission's place in the chain (heading_sample), identify a record.
    episodes = manifest.get("settings", {}).get("protocol") in CHAINED_PROTOCOLS
    second = arrays["heading_sample"] if episodes else np.zeros_like(arrays["index"])
    order = np.lexsort((second, arrays["index"]))
    arrays = {k: v[order] for k, v in arrays.items()}
    second = second[order]
    duplicated = np.flatnonzero((np.diff(arrays["index"]) == 0) & (np.diff(second) == 0))
    if duplicated.size:
        k = duplicated[0]
        what = (f"mission {int(second[k])} of episode {int(arrays['index'][k])}" if episodes
                else f"trial {int(arrays['index'][k])}")
        raise bad_value("dataset", str(path), f"{what} is stored twice")
    return arrays, manifest


def load_training_arrays(path) -> tuple[dict[str, np.ndarray], dict]:
    """The executed trials of a dataset as the networks' arrays (errors excluded):
    patch (N, 20, 20), feet (N, 6, 3), direction (N,), success, blc_success, scene,
    scene_kind, topology, kind; and the manifest (with ``fingerprint`` and ``fingerprints``)."""
    arrays, manifest = load_records(path)
    keep = arrays["status"] == "executed"
    chained = int(np.count_nonzero(arrays["status"] == "blc_only"))
    if chained and not keep.any():
        raise bad_value("dataset", str(path), f"has no executed missions, only {chained} labelled by the BLC "
                                              "alone (a plan chain walks nothing: no execution label to learn)")
    return {k: arrays[k][keep] for k in LEARNER_FIELDS}, manifest


# The trial settings that decide a label (TrialConfig's fields but the scene sampling's): datasets
# learned from together must agree on them (merge_training_arrays).
SAMPLING_SETTINGS = ("headings_per_scene", "foot_offset")


def merge_training_arrays(loaded, field: str = "--dataset") -> tuple[dict[str, np.ndarray], dict]:
    """One learner's arrays and manifest from several datasets' (``loaded``: (path, arrays,
    manifest) each, as load_training_arrays gives them), for a model that learns from a
    collection and the episodes of the planners' own routes together. They must be labelled
    by one BLC-robot system (the robot, BLC, controller and verdict fingerprints and the label
    settings, TrialConfig's but SAMPLING_SETTINGS, equal) and hold no scene in common (the
    split keeps a scene's records together); else QzError naming ``field``. The manifest's
    ``fingerprint`` is a digest of the datasets' own, its ``fingerprints`` theirs with
    ``scenes`` digested alike, and ``sources`` lists each dataset with its records."""
    from qz_drake.capability.trials import SETTINGS_BEFORE_THEY_EXISTED, TrialConfig

    if len(loaded) == 1:
        return loaded[0][1], loaded[0][2]
    label_keys = [f.name for f in dataclasses.fields(TrialConfig) if f.name not in SAMPLING_SETTINGS]
    first_path, _, first = loaded[0]
    defaults = {**dataclasses.asdict(TrialConfig()), **SETTINGS_BEFORE_THEY_EXISTED}

    def labels(manifest):
        settings = manifest.get("settings", {})
        return {k: settings.get(k, defaults[k]) for k in label_keys}

    first_labels = labels(first)
    scenes: dict[int, str] = {}
    for path, arrays, manifest in loaded:
        theirs, ours = manifest.get("fingerprints", {}), first.get("fingerprints", {})
        differ = [k for k in ("robot", "blc", "controller", "verdict") if theirs.get(k) != ours.get(k)]
        differ += [f"settings.{k}" for k, v in labels(manifest).items() if first_labels[k] != v]
        if differ:
            raise bad_value(field, str(path), f"its {', '.join(differ)} differ from {first_path}'s: labelled by "
                                              "another BLC-robot system (collect it again with this code)")
        for scene in np.unique(arrays["scene"]).tolist():
            if scenes.setdefault(int(scene), str(path)) != str(path):
                raise bad_value(field, str(path), f"scene {scene} is also {scenes[int(scene)]}'s: two collections of "
                                                  "the same scenes (another seed or protocol numbers them apart)")
        if set(arrays) != set(loaded[0][1]):
            raise bad_value(field, str(path), f"its arrays {sorted(arrays)} are not {first_path}'s {sorted(loaded[0][1])}")
    arrays = {k: np.concatenate([a[k] for _, a, _ in loaded]) for k in loaded[0][1]}
    parts = dict(first.get("fingerprints", {}))
    parts["scenes"] = _digest(*(m.get("fingerprints", {}).get("scenes", "") for _, _, m in loaded))
    manifest = {"fingerprint": _digest(*(m.get("fingerprint", "") for _, _, m in loaded)), "fingerprints": parts,
                "settings": dict(first.get("settings", {})),
                "sources": [{"dataset": str(path), "fingerprint": m.get("fingerprint", ""),
                             "protocol": m.get("settings", {}).get("protocol", "moves"), "records": int(len(a["scene"]))}
                            for path, a, m in loaded]}
    return arrays, manifest


def load_plan_arrays(path) -> tuple[dict[str, np.ndarray], dict]:
    """The missions of a dataset labelled by the BLC alone (status ``blc_only``: a plan chain
    collection, ``--protocol plans``) as the learners' arrays, as load_training_arrays gives the
    executed ones (``success`` there means nothing; ``blc_success`` is the label); and the
    manifest. A dataset with none is refused."""
    arrays, manifest = load_records(path)
    keep = arrays["status"] == "blc_only"
    if not keep.any():
        raise bad_value("plan dataset", str(path), "has no missions labelled by the BLC alone (collect one with "
                                                   "--protocol plans)")
    return {k: arrays[k][keep] for k in LEARNER_FIELDS}, manifest


def settings_dict(trial_config) -> dict:
    return dataclasses.asdict(trial_config)
