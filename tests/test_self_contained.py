"""A clone stands on its own (issue 39): no tracked file refers to a path outside the repository.

Someone who clones the repository alone has nothing beside it, so a scenario, test, notebook,
script, README line or package module that reads the shared folder beside the repository, a
folder of this machine's checkout by its absolute path, or climbs above the repository's root
from its own folder fails for them (or, in a test, skips and hides it). The data no one here
made live in ``data/external/`` and ``qz_drake/data/``.
"""

from __future__ import annotations

import hashlib
import re
import subprocess
from pathlib import Path, PurePosixPath

import pytest

REPO = Path(__file__).resolve().parents[1]
# What a user runs or reads; data/ holds results whose provenance fields may name the machine
# that produced them, and benchmarks/ its measurements.
SCOPE = ("scenarios", "tests", "notebooks", "scripts", "qz_drake", "docs", "README.md", "CHANGELOG.md",
         "Makefile", "pyproject.toml")
_SKIPPED_FOLDERS = {"__pycache__", ".ipynb_checkpoints", "out"}

# Absolute paths of a particular machine (a home, a work or scratch folder).
_ABSOLUTE = re.compile(r"(?<![\w.~/:-])/(?:work|home|Users|mnt|root|tmp)/[\w.-]")
# A relative path climbing with ../ (not a part of a longer run of dots).
_CLIMB = re.compile(r"(?<![\w.])((?:\.\./)+)([\w.*-][\w.*/-]*)?")
# The project's own folder beside the checkout, by name: shared/data, shared/papers, also as
# pathlib joins ("shared" / "data").
_SHARED = re.compile(r"""\bshared["']?\s*/\s*["']?(?:data|papers)\b""")
# Python climbing from its own file: Path(__file__).parent.parent / Path(__file__).parents[k].
_FROM_FILE = re.compile(r"Path\(__file__\)(?:\.resolve\(\))?((?:\.parent\b)*)(?:\.parents\[(\d+)\])?")
# The parent of a variable naming the repository's root (REPO.parent, repo_root.parent).
_ROOT_PARENT = re.compile(r"\b\w*(?:repo|root)\w*\.parent\b", re.IGNORECASE)


def outside_references(relative_path: str, text: str, repo: Path = REPO) -> list[str]:
    """The references to paths outside the repository in the tracked file ``relative_path``
    (relative to the repository's root) whose text is ``text``, as 'path:line: why' lines."""
    path = PurePosixPath(relative_path)
    depth = len(path.parts) - 1  # folders between the root and the file
    found = []
    for number, line in enumerate(text.splitlines(), start=1):
        where = f"{relative_path}:{number}"
        for match in _ABSOLUTE.finditer(line):
            found.append(f"{where}: absolute path {line[match.start():].split()[0]!r}")
        for match in _SHARED.finditer(line):
            found.append(f"{where}: the project's folder beside the checkout ({match.group(0)!r})")
        for match in _CLIMB.finditer(line):
            climbs = match.group(1).count("../")
            if climbs <= depth or _quoted_from_deeper_folder(path, climbs, match.group(2), repo):
                continue
            found.append(f"{where}: {match.group(0)!r} climbs {climbs} folders from {path.parent}/")
        if path.suffix != ".py":
            continue
        for match in _FROM_FILE.finditer(line):
            levels = match.group(1).count(".parent") + (int(match.group(2)) + 1 if match.group(2) else 0)
            if levels > len(path.parts):
                found.append(f"{where}: {match.group(0)!r} is {levels - len(path.parts)} folder(s) above the root")
        for match in _ROOT_PARENT.finditer(line):
            found.append(f"{where}: {match.group(0)!r} is the folder above the repository")
    return found


def _quoted_from_deeper_folder(path: PurePosixPath, climbs: int, rest: str | None, repo: Path) -> bool:
    """A Markdown file quoting a line of a deeper file (README quotes scenarios/*.yaml): the
    path is fine when what it names is in the repository."""
    return path.suffix == ".md" and bool(rest) and (repo / rest.rstrip("/.")).exists()


def tracked_files() -> list[str]:
    """The files in SCOPE: git's list in a checkout, else every file (a source archive)."""
    if (REPO / ".git").exists():
        listed = subprocess.run(["git", "ls-files", "-z", "--", *SCOPE], cwd=REPO, capture_output=True,
                                check=True).stdout.decode()
        return [name for name in listed.split("\0") if name]
    names = []
    for top in SCOPE:
        root = REPO / top
        files = [root] if root.is_file() else sorted(p for p in root.rglob("*") if p.is_file())
        names += [p.relative_to(REPO).as_posix() for p in files
                  if not _SKIPPED_FOLDERS & set(p.relative_to(REPO).parts)]
    return names


def _text(relative_path: str) -> str | None:
    data = (REPO / relative_path).read_bytes()
    if b"\0" in data:
        return None  # binary: pictures, weights, npz
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError:
        return None


def test_no_tracked_file_refers_to_a_path_outside_the_repository():
    files = tracked_files()
    assert "README.md" in files and any(f.startswith("scenarios/") for f in files)
    found = []
    for name in files:
        text = _text(name)
        # This file spells out the offenders it looks for.
        if text is not None and name != "tests/test_self_contained.py":
            found += outside_references(name, text)
    assert found == [], "\n".join(found)


# The shared folder beside the repository and this machine's checkout, spelled in parts so that
# this file, which lists them as offenders, holds no such path itself.
BESIDE = "../" + "shared"
CHECKOUT = "/" + "work/main"


# The offenders this test was written against (issue 39), one per form.
@pytest.mark.parametrize("relative_path, line", [
    ("scenarios/walk_own_terrain.yaml", f"  file: ../{BESIDE}/data/grid_map/heightmap_generated.png"),
    ("scenarios/x.yaml", "  file: ../../heightmap.png"),
    ("tests/terrain/test_heightmap.py",
     'SHARED_DATA = Path(__file__).resolve().parents[3] / "shared" / "data" / "grid_map"'),
    ("tests/terrain/test_x.py", "HERE = Path(__file__).parent.parent.parent.parent / 'maps'"),
    ("tests/planning/test_grid_search.py",
     'MOVINGAI = _REPO.parent / "shared" / "data" / "movingai"'),
    ("tests/test_new_user.py", "    copy.write_text(path.read_text().replace(REPO.parent, 'x'))"),
    ("tests/test_new_user.py", f"is looked for where the project keeps it (``<repo>/{BESIDE}/data``"),
    ("README.md", "project's `shared/papers/`):"),
    ("README.md", f"  file: ../{BESIDE}/data/grid_map/heightmap_generated.png"),
    ("Makefile", f"\tqz simulate {CHECKOUT}/scenarios/stand_flat.yaml"),
    ("notebooks/01.ipynb", '    "data = Path(\\"../../datasets/x\\")\\n",'),
    ("qz_drake/config.py", 'DEFAULT = "/home/someone/maps/terrain.png"'),
], ids=["scenario_shared", "scenario_above_root", "parents_index", "parent_chain", "root_parent",
        "repo_parent", "docstring", "readme_papers", "readme_quote", "makefile_absolute", "notebook",
        "package_absolute"])
def test_each_form_of_an_outside_reference_is_found(relative_path, line):
    assert outside_references(relative_path, f"first line\n{line}\n") != []
    assert outside_references(relative_path, f"first line\n{line}\n")[0].startswith(f"{relative_path}:2: ")


@pytest.mark.parametrize("relative_path, line", [
    ("scenarios/walk_own_terrain.yaml", "  file: ../data/external/grid_map/heightmap_generated.png"),
    ("README.md", "  file: ../data/external/grid_map/heightmap_generated.png"),
    ("notebooks/06_fig9_comparison.ipynb", '    "results = Path(\\"../data/fig9\\")\\n",'),
    ("qz_drake/robot/model.py", 'MODELS_DIR = Path(__file__).resolve().parents[2] / "models"'),
    ("tests/planning/test_grid_search.py", 'MOVINGAI = Path(__file__).resolve().parents[2] / "data"'),
    ("README.md", "The tests share a fixture ... / see the shared cores."),
    ("README.md", "qz simulate scenarios/stand_flat.yaml --out out/stand"),
], ids=["scenario_in_repo", "readme_quote_in_repo", "notebook_in_repo", "package_root", "test_root",
        "prose", "command"])
def test_paths_inside_the_repository_pass(relative_path, line):
    assert outside_references(relative_path, line) == []


def test_outside_data_is_byte_identical_to_its_source():
    # Each folder of data/external lists its files' SHA-256 as grid_map and pathfinding ship them.
    sums = sorted((REPO / "data" / "external").glob("*/SHA256SUMS"))
    assert [s.parent.name for s in sums] == ["grid_map", "movingai"]
    for listing in sums:
        for line in listing.read_text().splitlines():
            digest, name = line.split(maxsplit=1)
            path = (listing.parent / name).resolve()
            assert path.is_relative_to(REPO), line
            assert hashlib.sha256(path.read_bytes()).hexdigest() == digest, f"{path.relative_to(REPO)} changed"
