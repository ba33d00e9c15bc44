"""The ``qz`` command's argument helpers: the one-line parser, output folders and files checked
before any work runs, numbers, names and help texts built from the package's own tuples.

Building the parser imports nothing slow: the modules a help text lists names from (terrain
generators, topologies, materials) are imported when that help page is shown (LazyText), and
the commands import what they run when they run."""

from __future__ import annotations

import argparse
import math
import os
import re
from pathlib import Path

from qz_drake.errors import ConfigError, bad_value


# qz_drake.trajopt.parameters.TERMINAL_STANCES, here so that building the parser does not import
# the BLC (tests/test_cli_imports.py holds the two equal).
TERMINAL_STANCES = ("free", "canonical")

# qz_drake.config.WalkDrives's fields and BlcParameters.leg_clearance_softmin: the defaults of the
# options that decide how walks and trials are driven and solved, here so that building the
# parser imports neither pydrake nor the BLC (tests/test_cli_imports.py holds them equal).
WALK_CONTROL_MODE = "position"
WALK_TIME_STEP = 0.008  # [s]
LEG_CLEARANCE_SOFTMIN = None  # [1/m]; None: a row per link point

# A number or a comma-separated list of numbers, e.g. -5,-3 or -1e-2: an option's value, not an
# option. Maps are centred on the origin, so half of all coordinates are negative.
_NEGATIVE_NUMBERS = re.compile(r"^-(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?(,\s*[-+]?(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?)*$")


class LazyText:
    """A help text or epilog made by ``make()`` when its help page is first shown: the names it
    lists come from modules too slow to import for every command (OneLineParser)."""

    def __init__(self, make):
        self._make = make

    def __str__(self) -> str:
        return self._make()


class OneLineParser(argparse.ArgumentParser):
    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        # argparse reads "--start -5,-3" as two options; it accepts "-5" only.
        self._negative_number_matcher = _NEGATIVE_NUMBERS

    def add_argument(self, *args, **kwargs):
        # A LazyText help is set after argparse's checks of the new argument (newer Pythons
        # format its help there), so that adding it makes nothing.
        help_text = kwargs.pop("help", None) if isinstance(kwargs.get("help"), LazyText) else None
        action = super().add_argument(*args, **kwargs)
        if help_text is not None:
            action.help = help_text
        return action

    def format_help(self):
        # The LazyText help texts and epilog, made once, when this page is first shown.
        for action in self._actions:
            if isinstance(action.help, LazyText):
                action.help = str(action.help)
        if isinstance(self.epilog, LazyText):
            self.epilog = str(self.epilog)
        return super().format_help()

    def error(self, message):  # one line, exit 2, as for every other bad input
        self.exit(2, f"{self.prog}: error: {message}\n")


class PackageVersion(argparse._VersionAction):
    """``--version``: the installed package's version, looked up when asked for
    (importlib.metadata is slow to import)."""

    def __call__(self, parser, namespace, values, option_string=None):
        self.version = f"%(prog)s {package_version()}"
        super().__call__(parser, namespace, values, option_string)


def _check_can_write_into(path: Path, field: str, value) -> None:
    """Refuses ``path`` (a folder, existing or to be made) that this process cannot write into:
    found before the work runs, not when its results are saved."""
    existing = path.absolute()
    while not existing.exists():
        existing = existing.parent
    if not existing.is_dir():
        raise bad_value(field, str(value), f"cannot create a folder there: {existing} is a file")
    if not os.access(existing, os.W_OK | os.X_OK):
        what = "folder is" if existing == path.absolute() else f"folder would be made in {existing}, which is"
        raise bad_value(field, str(value), f"not writable: the {what} read-only for this user")


def output_folder(value, field: str = "--out", *, create: bool = True) -> Path:
    """The folder ``value`` names, created if needed (``create``); an empty name, an existing
    file, or a folder this process cannot write into or make is a ConfigError naming ``field``.
    With ``create=False`` only the checks run, so that bad input leaves nothing behind."""
    if value is None or not str(value).strip():
        raise bad_value(field, "" if value is None else str(value),
                        "empty; name a folder to write into (an empty name is the current folder)")
    path = Path(value)
    if path.exists() and not path.is_dir():
        raise ConfigError(f"{field} = {str(value)!r}: is a file; expected a folder to write into")
    _check_can_write_into(path, field, value)
    if not create:
        return path
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise ConfigError(f"{field} = {str(value)!r}: cannot create the folder ({e.strerror})") from None
    return path


def output_file(value, field: str = "--out") -> Path:
    """Checks that the file ``value`` names can be written (its folder is made when it is
    written); errors name ``field``. Nothing is created."""
    if value is None or not str(value).strip():
        raise bad_value(field, "" if value is None else str(value), "empty; name a file to write")
    path = Path(value)
    if path.is_dir():
        raise bad_value(field, str(value), "is a folder; expected a file to write")
    if path.exists() and not os.access(path, os.W_OK):
        raise bad_value(field, str(value), "not writable: the file is read-only for this user")
    _check_can_write_into(path.parent, field, value)
    return path


def check_output_argument(args) -> None:
    """Checks ``args.out`` before a command runs: a folder (the default) or, where the command
    sets ``out_kind="file"``, a file; ``out_kind=None`` (an input named out) skips it. A
    read-only --out once failed only after the simulation had run."""
    value, kind = getattr(args, "out", None), getattr(args, "out_kind", "folder")
    if value is None or kind is None:
        return
    if kind == "file":
        output_file(value)
    else:
        output_folder(value, create=False)


def positive_seconds(value, field: str, limit: float | None = None) -> float | None:
    """``value`` as a finite positive duration of simulated time, at most ``limit`` (default:
    qz_drake.config.MAX_SIMULATED_TIME); None passes through; errors name ``field``."""
    if value is None:
        return None
    if not (math.isfinite(value) and value > 0):
        raise ConfigError(f"{field} = {value}: must be a finite positive number of seconds")
    from qz_drake.config import MAX_SIMULATED_TIME

    limit = MAX_SIMULATED_TIME if limit is None else limit
    if value > limit:
        raise bad_value(field, value, f"longer than the limit of {limit:g} s of simulated time")
    return float(value)


def one_of(names) -> str:
    """Help text listing the valid ``names`` (the package's own tuples, so it cannot go stale)."""
    return "one of: " + ", ".join(names)


def terrain_kinds_text() -> str:
    """Each terrain kind with its parameters and their defaults, one line each (from the
    generators' signatures), for help pages."""
    import inspect

    from qz_drake.terrain import TERRAIN_KINDS, grid_map_terrain

    def default(value):
        return ",".join(value) if isinstance(value, tuple) else f"{value:g}" if isinstance(value, float) else value

    lines = ["terrain kinds and their parameters (KEY=default; sizes in m; seed=N seeds the terrain;",
             "a negative stairs rise, step height or slope angle_deg goes down; |rise| <= run):"]
    for kind, generator in {**TERRAIN_KINDS, "grid_map": grid_map_terrain}.items():
        parameters = inspect.signature(generator).parameters.values()
        lines.append(f"  {kind}: " + " ".join(f"{p.name}={default(p.default)}" for p in parameters
                                               if p.name != "seed"))
    return "\n".join(lines)


def terrain_names() -> tuple[str, ...]:
    """The names ``--terrain`` / ``qz terrain`` take: the generators and grid_map."""
    from qz_drake.terrain import TERRAIN_KINDS

    return (*TERRAIN_KINDS, "grid_map")


def topology_names() -> tuple[str, ...]:
    """The Qingzhui topologies (qz_drake.robot.topology.TOPOLOGY_NAMES), for help texts."""
    from qz_drake.robot.topology import TOPOLOGY_NAMES

    return TOPOLOGY_NAMES


def package_version() -> str:
    """The installed qz_drake's version (importlib.metadata)."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("qz_drake")
    except PackageNotFoundError:
        return "unknown (not installed; run make setup)"


def prepare_scenario(scenario):
    """The scenario's heightmap, after the checks that need it (start and waypoints on the map,
    a start the robot can stand on: qz_drake.scene.check_against_map)."""
    from qz_drake.scene import check_against_map, make_heightmap

    heightmap = make_heightmap(scenario.terrain, scenario.random_seed)
    check_against_map(scenario, heightmap)
    return heightmap


def parse_names(text: str | None, field: str, valid) -> tuple[str, ...] | None:
    """A comma-separated list of names, each one of ``valid``; None passes through. Errors
    name ``field`` and the bad name."""
    if text is None:
        return None
    names = tuple(n.strip() for n in text.split(",") if n.strip())
    if not names:
        raise bad_value(field, text, "expected a comma-separated list")
    for n in names:
        if n not in valid:
            raise bad_value(field, n, f"unknown (valid: {', '.join(valid)})")
    return names
