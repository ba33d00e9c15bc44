"""Errors a user can cause.

Every exception raised because of user input (a scenario file, a CLI argument, a map) is a
`QzError`; its message names the offending field and value so that the CLI can print it on
one line and exit with status 2.
"""


class QzError(Exception):
    """Base class of errors caused by user input."""


class ConfigError(QzError, ValueError):
    """A configuration field (YAML or argument) has a bad value."""


class TerrainError(QzError, ValueError):
    """A terrain or heightmap is malformed (NaN heights, bad resolution, unknown kind)."""


class KinematicsError(QzError, ValueError):
    """A point is out of a leg's reach, or a leg / topology name is unknown."""


def bad_value(field: str, value, why: str, error=ConfigError) -> QzError:
    """Builds an error whose message names `field` and `value`, e.g.
    ``terrain.resolution = -0.1: must be positive``."""
    return error(f"{field} = {value!r}: {why}")
