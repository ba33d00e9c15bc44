"""Every `qz` command README.md shows is one the command line takes, on files that exist.

The commands are read from README's shell blocks (a line continued with a backslash is one
command; a trailing comment or `&` is not part of it) and parsed by the `qz` parser itself, so
an option renamed or removed, or a scenario moved, fails here rather than in a new user's
shell. Running them is the other tests' job (tests/test_new_user.py runs the own-terrain
block; the scenarios, the BLC, the plan and the reports have tests of their own).
"""

from __future__ import annotations

import re
import shlex
from pathlib import Path

import pytest

from qz_drake.cli import build_parser

REPO = Path(__file__).resolve().parents[1]


def readme_commands() -> list[str]:
    blocks = re.findall(r"```sh\n(.*?)```", (REPO / "README.md").read_text(), flags=re.S)
    commands = []
    for block in blocks:
        text = re.sub(r"\\\n\s*", " ", block)  # continued lines
        for line in text.splitlines():
            line = re.sub(r"\s+#.*$", "", line).strip().rstrip("&").strip()
            for part in line.split(";"):
                part = part.strip()
                if part.startswith("qz ") or part.startswith(".venv/bin/python examples/"):
                    commands.append(part)
    return commands


COMMANDS = readme_commands()


def test_the_readme_shows_commands_of_every_group():
    groups = {c.split()[1] for c in COMMANDS if c.startswith("qz ")}
    assert {"simulate", "blc", "plan", "capability", "experiment", "bench", "robot-sim", "lcm-relay"} <= groups
    assert len(COMMANDS) > 40


@pytest.mark.parametrize("command", COMMANDS)
def test_a_readme_command_parses_and_its_inputs_exist(command):
    argv = shlex.split(command)
    if argv[0] != "qz":
        assert (REPO / argv[1]).is_file(), f"{command}: no {argv[1]}"
        return
    args = build_parser().parse_args(argv[1:])  # argparse exits on an unknown option or value
    # The files and folders it reads: a scenario, a dataset, a run folder, a model.
    for name in ("scenario", "dataset", "run", "model", "models"):
        value = getattr(args, name, None)
        if isinstance(value, str) and not value.startswith("out/") and "/" in value:
            assert (REPO / value).exists(), f"{command}: {name} {value} does not exist"


def test_what_readme_commands_write_goes_where_git_does_not_look():
    # A new user runs README's commands in a clone: whatever they write (--out, the plan
    # command's picture) lands under out/, which .gitignore names, so `git status` stays empty.
    assert "/out/" in (REPO / ".gitignore").read_text().split()
    for command in COMMANDS:
        argv = shlex.split(command)
        for option in ("--out", "--out-dir", "--output", "--png"):
            if option in argv:
                value = argv[argv.index(option) + 1]
                assert value.startswith("out/"), f"{command}: writes {value}, which git would see"
        assert "recertify" not in argv, f"{command}: rewrites a shipped dataset's manifest"
