"""The package's imports run one way (DESIGN.md "Layers").

The graph is read from the source with ``ast`` (imports at module level and inside functions
alike: a cycle hidden in a function is still a cycle), so it does not depend on what a test
run happened to import. ``python tests/test_layers.py`` prints its counts.
"""

from __future__ import annotations

import ast
import collections
import sys
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "qz_drake"

# The floors from the bottom up. A room is a folder of qz_drake or one of its top-level
# modules; an arrow may stay on its floor or go down, never up.
FLOORS = (
    ("qz_drake", "qz_drake.errors", "qz_drake.progress", "qz_drake.threads"),
    ("qz_drake.robot", "qz_drake.terrain", "qz_drake.state_layout"),
    ("qz_drake.config", "qz_drake.trajopt", "qz_drake.viz"),
    ("qz_drake.scene", "qz_drake.systems", "qz_drake.verdict"),
    ("qz_drake.sim_station", "qz_drake.hardware"),
    ("qz_drake.station",),
    # Build, run and judge a walk, given its route source.
    ("qz_drake.simulation",),
    ("qz_drake.capability", "qz_drake.classification"),
    ("qz_drake.planning",),
    ("qz_drake.experiments", "qz_drake.demo", "qz_drake.bench"),
    # The `qz` command: nothing in the package imports it.
    ("qz_drake.cli",),
)

# Arrows that may break the rules above, each with its reason (none left after issue 35). An
# entry here is a debt: it names the arrow and what removes it.
ALLOWED: dict[tuple[str, str], str] = {}


def modules() -> dict[str, Path]:
    found = {}
    for file in sorted(PACKAGE.rglob("*.py")):
        parts = list(file.relative_to(PACKAGE.parent).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts.pop()
        found[".".join(parts)] = file
    return found


def imports(found: dict[str, Path]) -> list[tuple[str, str, int, bool]]:
    """(importer, imported module, line, inside a function) for every import of a package module."""
    def owner(name: str) -> str:
        while name and name not in found:
            name = name.rpartition(".")[0]
        return name

    out = set()
    for name, file in found.items():
        package = name if file.name == "__init__.py" else name.rpartition(".")[0]

        def visit(node, in_function: bool) -> None:
            for child in ast.iter_child_nodes(node):
                targets = []
                if isinstance(child, ast.Import):
                    targets = [a.name for a in child.names]
                elif isinstance(child, ast.ImportFrom):
                    base = child.module or ""
                    if child.level:
                        parts = package.split(".")[: len(package.split(".")) - child.level + 1]
                        base = ".".join(parts + ([child.module] if child.module else []))
                    # `from package import module` imports the module; a name imports its owner.
                    targets = [f"{base}.{a.name}" if f"{base}.{a.name}" in found else base for a in child.names]
                for target in targets:
                    imported = owner(target) if target.startswith("qz_drake") else ""
                    if imported and imported != name:
                        out.add((name, imported, child.lineno, in_function))
                visit(child, in_function or isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda)))

        visit(ast.parse(file.read_text()), False)
    return sorted(out)


def room(module: str) -> str:
    return ".".join(module.split(".")[:2])


def floor(module: str) -> int:
    for level, rooms in enumerate(FLOORS):
        if room(module) in rooms:
            return level
    raise AssertionError(f"{module}: its room {room(module)} is on no floor of FLOORS")


def arrows() -> set[tuple[str, str]]:
    return {(a, b) for a, b, _, _ in imports(modules())}


def circles(edges) -> list[list[str]]:
    """The strongly connected components with more than one node (Tarjan)."""
    successors = collections.defaultdict(set)
    for a, b in edges:
        successors[a].add(b)
    index, low, stack, on_stack, found = {}, {}, [], set(), []

    def strong(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in sorted(successors[v]):
            if w not in index:
                strong(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                found.append(sorted(component))

    sys.setrecursionlimit(max(sys.getrecursionlimit(), 10000))
    for v in sorted(successors):
        if v not in index:
            strong(v)
    return found


def upward(edges) -> list[tuple[str, str]]:
    return sorted((a, b) for a, b in edges if floor(b) > floor(a))


def test_every_room_is_on_a_floor():
    for name in modules():
        floor(name)


def test_the_allowed_arrows_exist():
    # A stale entry would let the arrow come back unnoticed.
    assert not set(ALLOWED) - arrows(), sorted(set(ALLOWED) - arrows())


def test_no_arrow_runs_up():
    assert upward(arrows() - set(ALLOWED)) == []


def test_no_circle_between_modules():
    assert circles(arrows() - set(ALLOWED)) == []


def test_no_circle_between_rooms():
    rooms = {(room(a), room(b)) for a, b in arrows() - set(ALLOWED) if room(a) != room(b)}
    assert circles(rooms) == []


def test_nothing_imports_the_command_line():
    # The application layer sits on top: a domain module never reaches into it.
    users = sorted(a for a, b in arrows() - set(ALLOWED) if room(b) == "qz_drake.cli" and room(a) != "qz_drake.cli")
    assert users == []


def test_the_checks_see_an_upward_arrow_and_a_circle():
    assert upward({("qz_drake.robot.params", "qz_drake.simulation")}) == [("qz_drake.robot.params", "qz_drake.simulation")]
    assert circles({("a", "b"), ("b", "c"), ("c", "a"), ("c", "d")}) == [["a", "b", "c"]]


def counts() -> dict:
    found = modules()
    every = imports(found)
    edges = {(a, b) for a, b, _, _ in every}
    rooms = {(room(a), room(b)) for a, b in edges if room(a) != room(b)}
    return {"modules": len(found), "rooms": len({room(m) for m in found}), "room_arrows": len(rooms),
            "imports": len(every), "imports_in_functions": sum(1 for *_, inside in every if inside),
            "module_circles": len(circles(edges)), "room_circles": len(circles(rooms)),
            "upward_arrows": len(upward(edges)), "allowed": len(ALLOWED)}


if __name__ == "__main__":
    for key, value in counts().items():
        print(f"{key}: {value}")
    for a, b in upward(arrows()):
        print(f"  up: {a} -> {b}")
    for component in circles(arrows()):
        print(f"  circle: {' '.join(component)}")
