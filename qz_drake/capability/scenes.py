"""Scenes of the capability trials (paper 000 section III-B: 700 regular and 300 irregular),
and scenes like the worlds the planner must cross (issue 37).

"700 different scenes with regular terrains including flat ground; slops with different
gradient; stairs with different number, length, height, and width; gaps with different depth,
length, width, number and shape. And 300 different scenes with irregular terrains such as sine
and cosine shaped terrains, random roughness terrains and terrains with random obstacles."

Each scene kind is a small named function of a difficulty in [0, 1] and a seed, returning a
HeightMap centred on the robot's start (0, 0), ``SCENE_HALF_SIZE`` in every direction, so
that a trial can head anywhere (paper 000 turns the robot through 72 headings per scene).

The paper's kinds (``PAPER_KINDS``) put their features along the scene's +x axis at a seeded
distance from the start; the trial's heading decides whether the robot meets them head on,
obliquely or not at all. Their parameter ranges grow with difficulty; they were chosen so that
a third to two thirds of the trials fail (measured rates per kind: benchmarks/BENCHMARKS.md,
"capability").

The walk-like kinds (``WALK_KINDS``, issue 37) carry the features of the worlds CapPlanner's
walks cross, where walks ended on legs against stair risers and boxes: the Fig. 9 worlds
(qz_drake/experiments/worlds.py: stairs hills, boxes, both) and the demo's long-range world
(terrain.generators.long_range: pits and trenches). Difficulty 0, 0.5 and 1 are Fig. 9's
simple, medium and hard (the ``FIG9_*`` tables, which a test keeps equal to worlds.py's);
values between interpolate. Their features may lie at any heading and offset around the
start but never inside ``START_CLEAR_RADIUS``: a trial (an episode's first mission) starts on
level ground with all six feet at height 0 whatever its heading (later missions start wherever
the previous one ended, on a step or between boxes).

``scene_for(seed, index)`` draws the kind, the difficulty and the scene's own seed from (seed,
index): a scene is never stored, only its recipe. Half the scenes are the paper's kinds in the
paper's proportions (regular 70 %, irregular 30 % of that half, as its 700 / 300), half the
walk-like kinds, counted as a third family outside the paper's split: the model trained on the
paper's mix alone rated walks 2-5x too safe where they failed (issue 37), and half keeps the
paper's terrain classes (slopes, waves, roughness also lie on the demo's route) as well
represented as the walks' features. Scene seeds are drawn from ``SCENE_SEED_START`` on,
disjoint from the Fig. 9 worlds' task seeds (experiment 0-19, tunings from
worlds.TUNING_SEED_START = 1000, one per task), and scenes draw from ``default_rng(scene
seed)`` while a world draws from ``default_rng([terrain, difficulty, seed, 0xF19])``: no trial
scene repeats a world its planner is scored or tuned on.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from qz_drake.errors import bad_value
from qz_drake.terrain.generators import gap, stairs
from qz_drake.terrain.heightmap import HeightMap

# The scene reaches this far from the start along x and y. [m]
SCENE_HALF_SIZE = 2.5
# Cell size: the generators' default; box-like scenes have edges on cell boundaries. [m]
SCENE_RESOLUTION = 0.05

# (kind, share of all scenes). The paper's kinds make up half, regular 70 % and irregular 30 %
# of that half (paper 000 III-B); the walk-like kinds the other half (issue 37): Fig. 9's three
# terrains (stairs, obstacles, both) equally, the long-range world's pits less (one feature in
# six of its tiles).
SCENE_KINDS: tuple[tuple[str, float], ...] = (
    ("flat", 0.02), ("slope", 0.07), ("stairs", 0.13), ("gap", 0.13),
    ("waves", 0.05), ("rough", 0.05), ("obstacles", 0.05),
    ("stair_flight", 0.14), ("box_field", 0.14), ("stairs_among_boxes", 0.14), ("pits", 0.08),
)
REGULAR_KINDS = ("flat", "slope", "stairs", "gap")
IRREGULAR_KINDS = ("waves", "rough", "obstacles")
PAPER_KINDS = REGULAR_KINDS + IRREGULAR_KINDS
WALK_KINDS = ("stair_flight", "box_field", "stairs_among_boxes", "pits")
# Scene seeds are drawn from here to 2**31 - 1: far above the Fig. 9 worlds' task seeds
# (experiment 0-19, tunings from 1000 on, one per task).
SCENE_SEED_START = 2**24

# Walk-like features keep off this disc around the start: split_up's farthest foothold
# (0.83 m) + the trials' foot offsets (0.06 m) + the foot's radius (0.03 m) + half a cell of
# edge snapping, rounded up. A 0.7 m disc put a box under a foot at some headings. [m]
START_CLEAR_RADIUS = 1.0

# Fig. 9's worlds (experiments/worlds.py, paper 000 III-B) per level simple, medium, hard, at
# difficulty 0, 0.5, 1 here.
FIG9_LEVELS = (0.0, 0.5, 1.0)
# Stair rise. [m]
FIG9_RISE = (0.06, 0.12, 0.18)
# Range of a stairs hill's width. [m]
FIG9_HILL_WIDTH = ((2.0, 4.0), (4.0, 7.0), (7.0, 10.0))
# Range of box heights. [m]
FIG9_BOX_HEIGHT = ((0.05, 0.15), (0.05, 0.30), (0.10, 0.45))
# Share of the area boxes cover ("both": half of it).
FIG9_BOX_SHARE = (0.05, 0.12, 0.20)
# Range of a box's side. [m]
FIG9_BOX_SIDE = (0.3, 1.0)
# A hill: FIG9_STEPS steps up of FIG9_RUN, a FIG9_LANDING landing, as many down. [m]
FIG9_RUN = 0.4
FIG9_STEPS = 2
FIG9_LANDING = 1.0


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
        """In the paper's regular class (flat, slope, stairs, gap)."""
        return self.kind in REGULAR_KINDS

    @property
    def family(self) -> str:
        """The family: "regular" or "irregular" (the paper's 700 / 300), or "walk" (issue 37)."""
        return "regular" if self.regular else "irregular" if self.kind in IRREGULAR_KINDS else "walk"


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


# -- walk-like kinds (issue 37) -------------------------------------------------------------
def _fig9(table, difficulty: float) -> float:
    """A FIG9_* table's value at a difficulty: its simple, medium, hard at 0, 0.5, 1, linear between."""
    return float(np.interp(difficulty, FIG9_LEVELS, table))


# A feature's cross-section is made along +x by a terrain generator on a strip two cells wide
# and read at each scene cell's distance along the feature's heading. The strip is shifted this
# far so that every distance in the scene (half diagonal 3.6 m) and every feature lies on it. [m]
_STRIP_SHIFT = 6.0
_STRIP_LENGTH = 14.0
# Area of the scene outside the start's clear disc: boxes cover a share of it as Fig. 9's cover
# a share of the feature band. [m^2]
_OPEN_AREA = (2 * SCENE_HALF_SIZE) ** 2 - math.pi * START_CLEAR_RADIUS**2


def _cross_section(generator, start_x: float, **params) -> HeightMap:
    """``generator``'s terrain with its feature from ``start_x`` [m] on, on the strip."""
    return generator(start_x=start_x + _STRIP_SHIFT, size_x=_STRIP_LENGTH, size_y=2 * SCENE_RESOLUTION,
                     resolution=SCENE_RESOLUTION, **params)


def _along(section: HeightMap, u: np.ndarray) -> np.ndarray:
    """A cross-section's heights at distances ``u`` along the feature's heading (nearest cell)."""
    ix, _ = section.index(u + _STRIP_SHIFT, np.zeros_like(u))
    return section.heights[0, ix]


def _heading_frame(g: _Grid, heading: float, centre: float) -> tuple[np.ndarray, np.ndarray]:
    """(u, v) of every cell: its distance from the start along ``heading`` [rad] and its offset
    to the left of the feature's centre line, which passes ``centre`` [m] left of the start."""
    c, s = math.cos(heading), math.sin(heading)
    return g.x * c + g.y * s, -g.x * s + g.y * c - centre


def _place_boxes(g: _Grid, rng, *, sides, levels, area: float = math.inf, count: int | None = None,
                 reach: float = SCENE_HALF_SIZE, keep_off: np.ndarray | None = None) -> tuple[np.ndarray, int]:
    """Seeded axis-aligned boxes until they cover ``area`` [m^2] (overlaps counted twice, as
    Fig. 9's worlds count them) or number ``count``: sides in ``sides`` [m], levels in ``levels``
    [m] (negative: holes; where two overlap the one farther from 0 wins), inside the square of
    half side ``reach`` [m] around the start, none reaching into START_CLEAR_RADIUS or onto a
    cell of ``keep_off``. Returns the heights and the number placed."""
    heights = np.zeros(g.x.shape)
    placed, covered = 0, 0.0
    for _ in range(2000):
        if covered >= area or placed == count:
            break
        # Every attempt draws the same numbers, so a harder scene of the same seed places the
        # boxes of an easier one first.
        sx, sy = rng.uniform(*sides, 2)
        cx, cy = rng.uniform(-1.0, 1.0, 2) * (reach - np.array([sx, sy]) / 2)
        level = float(rng.uniform(*levels))
        x0, x1 = g.edge(cx - sx / 2), g.edge(cx + sx / 2)
        y0, y1 = g.edge(cy - sy / 2), g.edge(cy + sy / 2)
        if math.hypot(max(x0, 0.0, -x1), max(y0, 0.0, -y1)) < START_CLEAR_RADIUS:
            continue
        mask = g.box(x0, x1, y0, y1)
        if keep_off is not None and np.any(keep_off & mask):
            continue
        heights[mask] = np.maximum(heights[mask], level) if level > 0 else np.minimum(heights[mask], level)
        placed += 1
        covered += sx * sy
    return heights, placed


def _flight(g: _Grid, rng, difficulty: float) -> tuple[np.ndarray, dict]:
    """The heights and parameters of a stair flight (see stair_flight_scene)."""
    heading = float(rng.uniform(-math.pi, math.pi))
    shape = str(rng.choice(["hill", "up", "down"], p=[0.5, 0.25, 0.25]))
    steps = int(rng.integers(2, 4))
    run = float(rng.uniform(0.3, 0.5))
    rise = _fig9(FIG9_RISE, difficulty)
    width = float(rng.uniform(_fig9([w[0] for w in FIG9_HILL_WIDTH], difficulty),
                              _fig9([w[1] for w in FIG9_HILL_WIDTH], difficulty)))
    beside = bool(rng.random() < 0.3)
    if beside:
        near = float(rng.uniform(-1.5, 0.5))
        side = 1.0 if rng.random() < 0.5 else -1.0
        centre = side * (START_CLEAR_RADIUS + float(rng.uniform(0.0, 0.6)) + width / 2)
    else:
        near = START_CLEAR_RADIUS + float(rng.uniform(0.0, 0.8))
        centre = float(rng.uniform(-0.4, 0.4)) * width
    u, v = _heading_frame(g, heading, centre)
    signed = -rise if shape == "down" else rise
    profile = _along(_cross_section(stairs, near, rise=signed, run=run, count=steps), u)
    if shape == "hill":
        top_end = near + steps * run + FIG9_LANDING
        profile = profile + _along(_cross_section(stairs, top_end, rise=-rise, run=run, count=steps), u)
    heights = np.where(np.abs(v) < width / 2, profile, 0.0)
    return heights, {"heading": heading, "shape": shape, "steps": steps, "run": run, "rise": signed,
                     "width": width, "placement": "beside" if beside else "across", "near": near,
                     "centre": centre, "landing": FIG9_LANDING if shape == "hill" else 0.0}


def stair_flight_scene(difficulty: float, seed: int):
    """A flight of stairs at a seeded ``heading`` [rad], like Fig. 9's hills: a hill (half the
    scenes: ``steps`` = 2-3 steps up, Fig. 9's 1 m landing, as many down), or steps up (a
    quarter) or down (a quarter, ``rise`` < 0) to a level that continues off the scene. Rise
    0.06-0.18 m (Fig. 9's simple to hard: difficulty), run 0.3-0.5 m (Fig. 9: 0.4 m; the
    long-range world's pyramids: 0.3-0.5 m), width 2-4 m (difficulty 0) up to 7-10 m (1).

    The flight climbs along ``heading``; its centre line passes ``centre`` [m] left of the
    start. Across (70 %): the start lies within its width, the first nose ``near`` = 1-1.8 m
    ahead; beside (30 %): it runs past the start, its near side 1-1.6 m to the left or right,
    its first nose from 1.5 m behind to 0.5 m ahead. The trial's heading meets it head on,
    obliquely or along it. Noses lie on cell boundaries along the heading (terrain.stairs)."""
    rng = np.random.default_rng(seed)
    g = _Grid()
    heights, params = _flight(g, rng, difficulty)
    return params, g.map(heights)


def _box_heights(difficulty: float) -> tuple[float, float]:
    return (_fig9([h[0] for h in FIG9_BOX_HEIGHT], difficulty),
            _fig9([h[1] for h in FIG9_BOX_HEIGHT], difficulty))


def box_field_scene(difficulty: float, seed: int):
    """Fig. 9's obstacles around the start: boxes with sides of 0.3-1 m and heights of
    0.05-0.15 m (difficulty 0), 0.05-0.3 m (0.5) or 0.1-0.45 m (1), covering a ``share`` of the
    scene outside the start's clear disc of 5 %, 12 % or 20 % (difficulty) times a seeded
    ``density`` of 0.75-1.25; none within START_CLEAR_RADIUS of the start."""
    rng = np.random.default_rng(seed)
    g = _Grid()
    density = float(rng.uniform(0.75, 1.25))
    share = _fig9(FIG9_BOX_SHARE, difficulty) * density
    low, high = _box_heights(difficulty)
    heights, count = _place_boxes(g, rng, sides=FIG9_BOX_SIDE, levels=(low, high), area=share * _OPEN_AREA)
    return {"count": count, "share": share, "density": density, "min_height": low, "max_height": high}, \
        g.map(heights)


def stairs_among_boxes_scene(difficulty: float, seed: int):
    """Fig. 9's "both": the stair flight of stair_flight_scene with the same seed (the same
    flight), and boxes as box_field_scene's with half its share beside it, none on the flight."""
    rng = np.random.default_rng(seed)
    g = _Grid()
    flight, params = _flight(g, rng, difficulty)
    density = float(rng.uniform(0.75, 1.25))
    share = _fig9(FIG9_BOX_SHARE, difficulty) * density / 2
    low, high = _box_heights(difficulty)
    boxes, count = _place_boxes(g, rng, sides=FIG9_BOX_SIDE, levels=(low, high), area=share * _OPEN_AREA,
                                keep_off=flight != 0.0)
    params.update(count=count, share=share, density=density, min_height=low, max_height=high)
    return params, g.map(flight + boxes)


# Holes of the pits kind lie inside the square of this half side around the start. [m]
PIT_REACH = 2.0


def pits_scene(difficulty: float, seed: int):
    """The long-range world's pits and trenches (terrain.generators.long_range) near the start.
    Holes (65 %): ``count`` = 1-6 (difficulty) rectangles with sides from 0.25 m to 0.3-0.5 m
    and depths from 0.15 m to 0.25-0.4 m (difficulty), inside PIT_REACH of the start.
    Or a trench (35 %): ``width`` 0.15-0.45 m (difficulty), ``depth`` 0.3-0.6 m, ``length``
    2.4-3.2 m, across a seeded ``heading`` [rad] with its near edge ``near`` = 1-1.8 m ahead
    and its centre ``centre`` [m] left of the start (within 0.5 m). None within
    START_CLEAR_RADIUS of the start."""
    rng = np.random.default_rng(seed)
    g = _Grid()
    if rng.random() < 0.35:
        heading = float(rng.uniform(-math.pi, math.pi))
        width = _lerp(0.15, 0.45, difficulty)
        depth, length = float(rng.uniform(0.3, 0.6)), float(rng.uniform(2.4, 3.2))
        near = START_CLEAR_RADIUS + float(rng.uniform(0.0, 0.8))
        centre = float(rng.uniform(-0.5, 0.5))
        u, v = _heading_frame(g, heading, centre)
        heights = np.where(np.abs(v) < length / 2, _along(_cross_section(gap, near, width=width, depth=depth), u), 0.0)
        return {"shape": "trench", "count": 1, "heading": heading, "width": width, "depth": depth,
                "length": length, "near": near, "centre": centre}, g.map(heights)
    count = int(round(_lerp(1, 6, difficulty)))
    deepest, widest = _lerp(0.25, 0.4, difficulty), _lerp(0.3, 0.5, difficulty)
    heights, placed = _place_boxes(g, rng, sides=(0.25, widest), levels=(-deepest, -0.15), count=count,
                                   reach=PIT_REACH)
    return {"shape": "holes", "count": placed, "max_depth": deepest, "max_side": widest}, g.map(heights)


SCENE_FUNCTIONS = {
    "flat": flat_scene, "slope": slope_scene, "stairs": stairs_scene, "gap": gap_scene,
    "waves": waves_scene, "rough": rough_scene, "obstacles": obstacles_scene,
    "stair_flight": stair_flight_scene, "box_field": box_field_scene,
    "stairs_among_boxes": stairs_among_boxes_scene, "pits": pits_scene,
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
    return kind, float(rng.uniform(0.0, 1.0)), int(rng.integers(SCENE_SEED_START, 2**31 - 1))


def scene_for(seed: int, index: int) -> Scene:
    """Scene ``index`` of a collection seeded ``seed``."""
    kind, difficulty, scene_seed = scene_recipe(seed, index)
    return make_scene(kind, difficulty, scene_seed, index)
