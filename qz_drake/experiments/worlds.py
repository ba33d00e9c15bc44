"""Worlds and tasks of the planner comparison (paper 000 III-B, Fig. 9).

"Terrains with stairs, obstacles and both are created in simulation, and the complexity are
distinguished by simple, medium and hard, which have corresponding stair width, height and
obstacle density. Then, we give Qingzhui 20 locomotion tasks in these terrains."

Each task has its own seeded world: WORLD_SIZE_X x WORLD_SIZE_Y metres centred on the origin,
flat outside a feature band |x| < BAND_HALF_WIDTH, the start west of the band and the goal east
of it, 8-15 m apart, so every route meets the features. The parameters per difficulty:

======  ====================================  ==========================================
level   stairs: rise [m] / hill width [m]      obstacles: heights [m] / share of the band
======  ====================================  ==========================================
simple  0.06 / 2-4 (easy to walk around)       0.05-0.15 / 5 %
medium  0.12 / 4-7                             0.05-0.30 / 12 %
hard    0.18 / 7-10 (spans most of the world)  0.10-0.45 / 20 %
======  ====================================  ==========================================

A stairs hill is a flight of two steps up (runs of 0.4 m), a 1 m landing and two steps down,
across the band at a seeded lateral position; "both" puts one hill and half the obstacles.
Task seeds 0 to TASKS_PER_CELL - 1 are the experiment's; planners are tuned on seeds from
TUNING_SEED_START on, never on the tasks they are scored on; the capability model is checked
against whole walks on seeds from VALIDATION_SEED_START on (issue 37), which neither the
experiment nor a tuning walks.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from qz_drake.errors import bad_value
from qz_drake.terrain.heightmap import HeightMap

TERRAINS: tuple[str, ...] = ("stairs", "obstacles", "both")
# The planners compared on these worlds, as a reader calls them.
PLANNER_NAMES = {"capplanner": "CapPlanner", "astar": "A*", "astar_learned": "learned A*"}
DIFFICULTIES: tuple[str, ...] = ("simple", "medium", "hard")
# Tasks per terrain and difficulty (issue 38): 50 give 80 % power to find a 10-point paired
# difference on medium + hard at McNemar p < 0.01 when 25 % of the tasks are discordant (the
# first run's share: 30 of its 120 medium and hard tasks; qz experiment report's "Design");
# that run had 20, and 29 % power.
TASKS_PER_CELL = 50
VALIDATION_SEED_START = 500
TUNING_SEED_START = 1000
# The worlds whose walks are data (issue 54: CapPlanner's data from its own routes): apart from
# every other role's, as the capability scenes' seeds are (capability.scenes.SCENE_SEED_START).
TRAINING_SEED_START = 2 ** 24
WORLD_SIZE_X = 18.0
WORLD_SIZE_Y = 10.0
BAND_HALF_WIDTH = 3.0
RESOLUTION = 0.05

_STAIRS = {"simple": (0.06, (2.0, 4.0)), "medium": (0.12, (4.0, 7.0)), "hard": (0.18, (7.0, 10.0))}
_OBSTACLES = {"simple": ((0.05, 0.15), 0.05), "medium": ((0.05, 0.30), 0.12), "hard": ((0.10, 0.45), 0.20)}
_RUN = 0.4
_STEPS = 2
_LANDING = 1.0


@dataclasses.dataclass(frozen=True)
class Task:
    """One locomotion task: a world and a start and goal on it."""

    terrain: str
    difficulty: str
    seed: int
    start: tuple[float, float]
    start_yaw: float
    goal: tuple[float, float]
    heightmap: HeightMap

    @property
    def distance(self) -> float:
        return math.hypot(self.goal[0] - self.start[0], self.goal[1] - self.start[1])

    @property
    def task_id(self) -> str:
        return f"{self.terrain}-{self.difficulty}-{self.seed}"


def _grid(scale: float = 1.0):
    nx, ny = int(round(scale * WORLD_SIZE_X / RESOLUTION)), int(round(scale * WORLD_SIZE_Y / RESOLUTION))
    origin = (-nx * RESOLUTION / 2 + RESOLUTION / 2, -ny * RESOLUTION / 2 + RESOLUTION / 2)
    x = origin[0] + RESOLUTION * np.arange(nx)
    y = origin[1] + RESOLUTION * np.arange(ny)
    gx, gy = np.meshgrid(x, y)
    return gx, gy, origin


def _snap(v: float) -> float:
    return round(v / RESOLUTION) * RESOLUTION


def _stairs_hill(heights, gx, gy, rng, rise: float, width_range, scale: float) -> None:
    size_y, band = scale * WORLD_SIZE_Y, scale * BAND_HALF_WIDTH
    width = min(rng.uniform(*width_range), size_y)
    cy = rng.uniform(-size_y / 2 + width / 2, size_y / 2 - width / 2) if width < size_y else 0.0
    length = 2 * _STEPS * _RUN + _LANDING
    x0 = _snap(rng.uniform(-band, max(band - length, -band)))
    lateral = (gy >= _snap(cy - width / 2)) & (gy < _snap(cy + width / 2))
    level = np.zeros_like(heights)
    for k in range(_STEPS):
        level += (gx >= x0 + k * _RUN) & (gx < x0 + length - k * _RUN)
    heights[:] = np.maximum(heights, np.where(lateral, rise * level, 0.0))


def _obstacles(heights, gx, gy, rng, height_range, share: float, scale: float) -> None:
    half_band, size_y = scale * BAND_HALF_WIDTH, scale * WORLD_SIZE_Y
    area = 2 * half_band * size_y
    covered = 0.0
    for _ in range(2000):
        if covered >= share * area:
            break
        sx, sy = rng.uniform(0.3, 1.0, 2)
        cx = rng.uniform(-half_band + sx / 2, half_band - sx / 2)
        cy = rng.uniform(-size_y / 2 + sy / 2, size_y / 2 - sy / 2)
        mask = (gx >= _snap(cx - sx / 2)) & (gx < _snap(cx + sx / 2)) & \
               (gy >= _snap(cy - sy / 2)) & (gy < _snap(cy + sy / 2))
        heights[mask] = np.maximum(heights[mask], rng.uniform(*height_range))
        covered += sx * sy


def make_task(terrain: str, difficulty: str, seed: int, scale: float = 1.0) -> Task:
    """The task (and its world) of a terrain, a difficulty and a seed. ``scale`` < 1 shrinks
    the world, the band and the start-goal distance (not the features): a tiny task for tests."""
    if terrain not in TERRAINS:
        raise bad_value("--terrains", terrain, f"expected one of {', '.join(TERRAINS)}")
    if difficulty not in DIFFICULTIES:
        raise bad_value("--difficulties", difficulty, f"expected one of {', '.join(DIFFICULTIES)}")
    rng = np.random.default_rng([TERRAINS.index(terrain), DIFFICULTIES.index(difficulty), int(seed), 0xF19])
    if not 0.2 <= scale <= 1.0:
        raise bad_value("scale", scale, "must be within [0.2, 1]")
    gx, gy, origin = _grid(scale)
    heights = np.zeros(gx.shape)
    rise, widths = _STAIRS[difficulty]
    height_range, share = _OBSTACLES[difficulty]
    if terrain in ("stairs", "both"):
        for _ in range(2 if terrain == "stairs" else 1):
            _stairs_hill(heights, gx, gy, rng, rise, widths, scale)
    if terrain in ("obstacles", "both"):
        _obstacles(heights, gx, gy, rng, height_range, share if terrain == "obstacles" else share / 2, scale)
    s = scale
    while True:  # start and goal 8-15 m apart, on flat ground outside the band
        start = (float(rng.uniform(-7.5 * s, -4.0 * s)), float(rng.uniform(-3.0 * s, 3.0 * s)))
        goal = (float(rng.uniform(4.0 * s, 7.5 * s)), float(rng.uniform(-3.0 * s, 3.0 * s)))
        if 8.0 * s <= math.hypot(goal[0] - start[0], goal[1] - start[1]) <= 15.0 * s:
            break
    yaw = math.atan2(goal[1] - start[1], goal[0] - start[0])
    return Task(terrain=terrain, difficulty=difficulty, seed=int(seed), start=start, start_yaw=yaw,
                goal=goal, heightmap=HeightMap(heights, RESOLUTION, origin))


def seed_role(seed: int) -> str:
    """What the worlds of ``seed`` are for: "experiment" (0-49, the first decisive run's, and
    100-149, the fresh run's), "reserved" (50-99: checks outside the project; never walked,
    tuned, pictured or trained on here), "validation" (500-999), "tuning" (1000 up to
    TRAINING_SEED_START), "training" (from TRAINING_SEED_START: walks whose missions may be
    learned from), "unassigned" (150-499)."""
    seed = int(seed)
    if 50 <= seed < 100:
        return "reserved"
    if 0 <= seed < 150:
        return "experiment"
    if VALIDATION_SEED_START <= seed < TUNING_SEED_START:
        return "validation"
    if TUNING_SEED_START <= seed < TRAINING_SEED_START:
        return "tuning"
    return "training" if seed >= TRAINING_SEED_START else "unassigned"


def experiment_tasks(terrains=TERRAINS, difficulties=DIFFICULTIES, tasks: int = TASKS_PER_CELL,
                     first_seed: int = 0) -> list[Task]:
    """The tasks of the comparison (seeds first_seed .. first_seed + tasks - 1 per cell)."""
    return [make_task(t, d, s) for t in terrains for d in difficulties
            for s in range(first_seed, first_seed + tasks)]
