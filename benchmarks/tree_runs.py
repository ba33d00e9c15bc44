"""One source tree's run of a benchmark script in a fresh interpreter: what the side-by-side
benchmarks (``*_side_by_side.py``) compare, one tree's runs against another's, alternating.

    git worktree add --detach /tmp/base COMMIT
    run_in_tree("/tmp/base", SCRIPT, arg, ...)   # SCRIPT's last printed line, as JSON
"""

import json
import os
import subprocess
import sys

# Run before every script: qz_drake comes from the tree (sys.argv[1]), not from the editable
# install (its finder is taken out of sys.meta_path), and the tree's benchmarks are importable.
PREAMBLE = r"""
import sys
sys.meta_path[:] = [f for f in sys.meta_path if "editable" not in type(f).__name__.lower()
                    and "editable" not in str(getattr(f, "__module__", "")).lower()]
sys.path[:0] = [sys.argv[1], sys.argv[1] + "/benchmarks"]
import qz_drake
assert qz_drake.__file__.startswith(sys.argv[1]), qz_drake.__file__
"""


def run_in_tree(root, script: str, *args, env=None) -> dict:
    """The JSON of the last line ``script`` prints, run after PREAMBLE in a fresh interpreter
    with ``sys.argv`` = ["-c", the tree's absolute path, *args]; a failed run ends this program
    with its error output."""
    run = subprocess.run([sys.executable, "-c", PREAMBLE + script, os.path.abspath(root), *map(str, args)],
                         capture_output=True, text=True, env=env)
    if run.returncode:
        sys.exit(run.stderr[-3000:])
    return json.loads(run.stdout.strip().splitlines()[-1])


def blc_changes(items, option: str) -> dict:
    """``option``'s NAME=VALUE items as BlcParameters fields, each value read as JSON (a bare
    word stays text); a name that is not a field ends the program naming it."""
    import dataclasses

    from qz_drake.trajopt.parameters import BlcParameters

    fields = {f.name for f in dataclasses.fields(BlcParameters)}
    out = {}
    for item in items:
        name, sep, value = item.partition("=")
        if not sep or name not in fields:
            sys.exit(f"{option} {item!r}: expected NAME=VALUE with a BlcParameters field")
        try:
            out[name] = json.loads(value)
        except json.JSONDecodeError:
            out[name] = value
    return out
