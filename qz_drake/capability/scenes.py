"""Scenes of the capability trials (paper 000 section III-B): 700 regular and 300 irregular.

"700 different scenes with regular terrains including flat ground; slops with different
gradient; stairs with different number, length, height, and width; gaps with different depth,
length, width, number and shape. And 300 different scenes with irregular terrains such as sine
and cosine shaped terrains, random roughness terrains and terrains with random obstacles."

Each scene kind is a small named function of a difficulty in [0, 1] and a seed, returning a
HeightMap centred on the robot's start (0, 0), ``SCENE_HALF_SIZE`` in every direction, so
that a trial can head anywhere (paper 000 turns the robot through 72 headings per scene). The
features sit along the scene's +x axis at a seeded distance from the start; the trial's
heading decides whether the robot meets them head on, obliquely or not at all. The parameter
ranges grow with difficulty; they were chosen so that a third to two thirds of the trials
fail (measured rates per kind: benchmarks/BENCHMARKS.md, "capability").

``scene_for(seed, index)`` draws the kind (regular 70 %, irregular 30 %, as the paper's 700 /
300), the difficulty and the scene's own seed from (seed, index): a scene is never stored,
only its recipe.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from qz_drake.errors import bad_value
from qz_drake.terrain.heightmap import HeightMap

# The scene reaches this far from the start along x and y. [m]
SCENE_HALF_SIZE = 2.5
# Cell size: the generators' default; box-like scenes have edges on cell boundaries. [m]
SCENE_RESOLUTION = 0.05

# (kind, share of all scenes). Regular: 70 %, irregular: 30 % (paper 000 III-B).
SCENE_KINDS: tuple[tuple[str, float], ...] = (
    ("flat", 0.04), ("slope", 0.14), ("stairs", 0.26), ("gap", 0.26),
    ("waves", 0.10), ("rough", 0.10), ("obstacles", 0.10),
)
REGULAR_KINDS = ("flat", "slope", "stairs", "gap")
IRREGULAR_KINDS = ("waves", "rough", "obstacles")


@dataclasses.dataclass(frozen=True)
class Scene:
    """One scene: its recipe (kind, difficulty, seed), the parameters drawn and the map."""

    index: int
    kind: str
    difficulty: float
    seed: int
    params: dict
    heightmap: HeightMap

    @property
    def regular(self) -> bool:
        return self.kind in REGULAR_KINDS


class _Grid:
    """Cell centres of a scene, with edges snapped to cell boundaries (like the generators)."""

    def __init__(self, half: float = SCENE_HALF_SIZE, resolution: float = SCENE_RESOLUTION):
        n = int(round(2 * half / resolution))
        self.resolution = resolution
        self.origin = (-half + resolution / 2, -half + resolution / 2)
        c = self.origin[0] + resolution * np.arange(n)
        self.x, self.y = np.meshgrid(c, c)  # [iy, ix]

    def edge(self, position: float) -> float:
        if not math.isfinite(position):
            return position
        return round(position / self.resolution) * self.resolution

    def band(self, start: float, end: float) -> np.ndarray:
        return (self.x >= self.edge(start)) & (self.x < self.edge(end))

    def box(self, x0: float, x1: float, y0: float, y1: float) -> np.ndarray:
        return self.band(x0, x1) & (self.y >= self.edge(y0)) & (self.y < self.edge(y1))

    def map(self, heights) -> HeightMap:
        return HeightMap(np.broadcast_to(np.asarray(heights, dtype=float), self.x.shape).copy(),
                         self.resolution, self.origin)


def _lerp(low: float, high: float, difficulty: float) -> float:
    return low + (high - low) * difficulty


def _offset(rng) -> float:
    """Distance from the start to a feature's near edge. [m] A foot may already stand on it:
    the start state of a mission is wherever the previous one ended."""
    return float(rng.uniform(0.25, 1.1))


def flat_scene(difficulty: float, seed: int):
    """Level ground (the easy end of the distribution; difficulty is unused)."""
    del difficulty, seed
    return {}, _Grid().map(0.0)


def slope_scene(difficulty: float, seed: int):
    """An incline of 4-30 deg (difficulty), up or down, beginning at a seeded distance ahead."""
    rng = np.random.default_rng(seed)
    g = _Grid()
    angle = _lerp(4.0, 30.0, difficulty) * (1 if rng.random() < 0.6 else -1)
    start = _offset(rng) - 0.3
    heights = np.clip(g.x - start, 0.0, None) * math.tan(math.radians(angle))
    return {"angle_deg": angle, "start_x": start}, g.map(heights)


def stairs_scene(difficulty: float, seed: int):
    """1-4 steps (up 65 %, down 35 %), rise 0.04-0.26 m and run 0.25-0.5 m (difficulty sets
    the rise and the shortest run), 1.2 m wide up to the whole scene (a narrow flight can be
    walked around)."""
    rng = np.random.default_rng(seed)
    g = _Grid()
    rise = _lerp(0.04, 0.26, difficulty) * rng.uniform(0.8, 1.0)
    rise *= 1 if rng.random() < 0.65 else -1
    run = rng.uniform(_lerp(0.45, 0.25, difficulty), 0.5)
    count = int(rng.integers(1, 5))
    start = _offset(rng)
    width = float(rng.choice([2 * SCENE_HALF_SIZE, rng.uniform(1.2, 3.0)]))
    centre_y = 0.0 if width >= 2 * SCENE_HALF_SIZE else float(rng.uniform(-0.5, 0.5))
    steps = sum(g.band(start + k * run, math.inf).astype(float) for k in range(count))
    lateral = (g.y >= g.edge(centre_y - width / 2)) & (g.y < g.edge(centre_y + width / 2))
    heights = rise * steps * lateral
    return {"rise": rise, "run": run, "count": count, "start_x": start, "width": width,
            "centre_y": centre_y}, g.map(heights)


def gap_scene(difficulty: float, seed: int):
    """1-2 gaps 0.08-0.5 m wide (difficulty) and 0.1-0.5 m deep: a trench across the scene or a
    rectangular hole 0.6-2 m long (the paper's "shape"); a second one 0.5-1 m behind."""
    rng = np.random.default_rng(seed)
    g = _Grid()
    width = _lerp(0.08, 0.5, difficulty) * rng.uniform(0.8, 1.0)
    depth = float(rng.uniform(0.1, 0.5))
    count = int(rng.integers(1, 3))
    trench = bool(rng.random() < 0.6)
    length = 2 * SCENE_HALF_SIZE if trench else float(rng.uniform(0.6, 2.0))
    centre_y = 0.0 if trench else float(rng.uniform(-0.4, 0.4))
    start = _offset(rng)
    heights = np.zeros(g.x.shape)
    near = start
    for _ in range(count):
        heights[g.box(near, near + width, centre_y - length / 2, centre_y + length / 2)] = -depth
        near += width + rng.uniform(0.5, 1.0)
    return {"width": width, "depth": depth, "count": count, "shape": "trench" if trench else "hole",
            "length": length, "start_x": start}, g.map(heights)


def waves_scene(difficulty: float, seed: int):
    """A sine x cosine surface (the paper's sine and cosine terrains): amplitude 0.02-0.15 m
    (difficulty), wavelength 0.8-2.5 m, random phase."""
    rng = np.random.default_rng(seed)
    g = _Grid()
    amplitude = _lerp(0.02, 0.15, difficulty)
    wavelength = float(rng.uniform(0.8, 2.5))
    k = 2 * math.pi / wavelength
    px, py = rng.uniform(0, 2 * math.pi, 2)
    heights = amplitude * np.sin(k * g.x + px) * np.cos(k * g.y + py)
    heights -= heights[g.x.shape[0] // 2, g.x.shape[1] // 2]
    return {"amplitude": amplitude, "wavelength": wavelength}, g.map(heights)


def rough_scene(difficulty: float, seed: int):
    """Smoothed random roughness: peak deviation 0.02-0.12 m (difficulty), correlation
    length 0.05-0.3 m."""
    from scipy.ndimage import gaussian_filter

    rng = np.random.default_rng(seed)
    g = _Grid()
    amplitude = _lerp(0.02, 0.12, difficulty)
    correlation = float(rng.uniform(0.05, 0.3))
    field = gaussian_filter(rng.standard_normal(g.x.shape), correlation / g.resolution, mode="reflect")
    field -= field.mean()
    field *= amplitude / max(np.abs(field).max(), 1e-12)
    return {"amplitude": amplitude, "correlation_length": correlation}, g.map(field)


def obstacles_scene(difficulty: float, seed: int):
    """3-14 random boxes (difficulty sets the count and the tallest), 0.2-0.7 m wide and
    0.03-0.4 m high, none on the start's 0.3 m disc."""
    rng = np.random.default_rng(seed)
    g = _Grid()
    count = int(round(_lerp(3, 14, difficulty)))
    top = _lerp(0.1, 0.4, difficulty)
    heights = np.zeros(g.x.shape)
    placed = 0
    for _ in range(200):
        if placed == count:
            break
        sx, sy = rng.uniform(0.2, 0.7, 2)
        cx, cy = rng.uniform(-SCENE_HALF_SIZE + 0.3, SCENE_HALF_SIZE - 0.3, 2)
        # Keep the start's disc clear (nearest point of the box to the origin).
        nx = max(abs(cx) - sx / 2, 0.0)
        ny = max(abs(cy) - sy / 2, 0.0)
        if math.hypot(nx, ny) < 0.3:
            continue
        mask = g.box(cx - sx / 2, cx + sx / 2, cy - sy / 2, cy + sy / 2)
        heights[mask] = np.maximum(heights[mask], rng.uniform(0.03, top))
        placed += 1
    return {"count": placed, "max_height": top}, g.map(heights)


SCENE_FUNCTIONS = {
    "flat": flat_scene, "slope": slope_scene, "stairs": stairs_scene, "gap": gap_scene,
    "waves": waves_scene, "rough": rough_scene, "obstacles": obstacles_scene,
}


def make_scene(kind: str, difficulty: float, seed: int, index: int = 0) -> Scene:
    """The scene of a kind at a difficulty in [0, 1] and a seed."""
    if kind not in SCENE_FUNCTIONS:
        raise bad_value("scene.kind", kind, f"expected one of {', '.join(SCENE_FUNCTIONS)}")
    if not (isinstance(difficulty, (int, float)) and 0.0 <= difficulty <= 1.0):
        raise bad_value("scene.difficulty", difficulty, "must be within [0, 1]")
    params, heightmap = SCENE_FUNCTIONS[kind](float(difficulty), int(seed))
    return Scene(index=int(index), kind=kind, difficulty=float(difficulty), seed=int(seed),
                 params=params, heightmap=heightmap)


def scene_recipe(seed: int, index: int) -> tuple[str, float, int]:
    """(kind, difficulty, scene seed) of scene ``index`` of a collection seeded ``seed``."""
    rng = np.random.default_rng([int(seed), int(index), 0x5CE4E])
    kinds = [k for k, _ in SCENE_KINDS]
    shares = np.array([s for _, s in SCENE_KINDS])
    kind = kinds[int(rng.choice(len(kinds), p=shares / shares.sum()))]
    return kind, float(rng.uniform(0.0, 1.0)), int(rng.integers(0, 2**31 - 1))


def scene_for(seed: int, index: int) -> Scene:
    """Scene ``index`` of a collection seeded ``seed``."""
    kind, difficulty, scene_seed = scene_recipe(seed, index)
    return make_scene(kind, difficulty, scene_seed, index)
