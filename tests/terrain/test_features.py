import math

import numpy as np
import pytest

from qz_drake.errors import TerrainError
from qz_drake.terrain import HeightMap, grid_map_terrain
from qz_drake.terrain.features import (BodyCostConfig, BodyFeatureConfig, CostMapConfig, FootholdCostConfig,
                                       FootholdFeatureConfig, Footprint, body_cost, body_features, build_cost_map, feet_cost,
                                       foothold_cost, foothold_features, traversable, triangle_mask)

RES = 0.05


def _grid(shape):
    rows, cols = np.indices(shape)
    return cols * RES, rows * RES  # x, y


def _disc_cells(z, row, col, radius):
    """Heights and (dx, dy) of the disc around a cell, outside cells clamped to the border."""
    r = int(math.floor(radius / RES + 1e-9))
    H, W = z.shape
    out = []
    for i in range(-r, r + 1):
        for j in range(-r, r + 1):
            if (i * RES) ** 2 + (j * RES) ** 2 <= radius ** 2 + 1e-12:
                out.append((j * RES, i * RES, z[min(max(row + i, 0), H - 1), min(max(col + j, 0), W - 1)]))
    return np.array(out)


def _reference_step(z, row, col, config):
    """Eq. 9 cell by cell, as the feature's docstring states it."""
    H, W = z.shape
    w = int(round(config.step_window / RES))
    r = int(math.floor(config.radius / RES + 1e-9))
    clamp = lambda i, j: z[min(max(i, 0), H - 1), min(max(j, 0), W - 1)]
    h_max, steep = 0.0, 0
    for i in range(-r, r + 1):
        for j in range(-r, r + 1):
            if i * i + j * j > (config.radius / RES) ** 2 + 1e-9:
                continue
            g = (row + i, col + j)
            best, best_dist = 0.0, 1.0
            for a in range(-w, w + 1):
                for b in range(-w, w + 1):
                    diff = abs(clamp(g[0] + a, g[1] + b) - clamp(*g))
                    dist = math.hypot(a, b) * RES
                    if diff > best or (diff == best and diff > 0 and dist < best_dist):
                        best, best_dist = diff, dist
            h_max = max(h_max, best)
            steep += best / best_dist > config.critical_slope
    return h_max * min(1.0, steep / config.critical_count)


@pytest.fixture(scope="module")
def rough_terrain():
    rng = np.random.default_rng(0)
    z = np.cumsum(np.cumsum(rng.normal(0, 0.004, (30, 36)), axis=0), axis=1) * 0.3
    z[12:20, 15:24] += 0.12  # a block: real step edges
    return z


def test_body_features_match_cell_by_cell_definitions(rough_terrain):
    z = rough_terrain
    config = BodyFeatureConfig(radius=0.2, step_window=0.1, critical_slope=1.0, critical_count=8)
    features = body_features(z, RES, config=config)
    for row, col in [(0, 0), (2, 35), (15, 14), (11, 20), (29, 17), (20, 24)]:
        dx, dy, h = _disc_cells(z, row, col, config.radius).T
        (a, b, _), *_ = np.linalg.lstsq(np.stack([dx, dy, np.ones_like(dx)], axis=1), h, rcond=None)
        assert features.slope[row, col] == pytest.approx(math.atan(math.hypot(a, b)), abs=1e-9)
        assert features.roughness[row, col] == pytest.approx(h.std(), abs=1e-7)
        assert features.step_height[row, col] == pytest.approx(_reference_step(z, row, col, config), abs=1e-9)


def test_plane_and_ramp():
    x, y = _grid((60, 70))
    z = 0.3 * x - 0.2 * y
    features = body_features(z, RES)
    inner = (slice(20, 40), slice(20, 50))
    assert np.allclose(features.slope[inner], math.atan(math.hypot(0.3, 0.2)))
    _, dx, _ = _disc_cells(z, 30, 30, 0.7).T
    # Std of a plane's heights over a disc: |grad| * sqrt(mean dx^2).
    assert np.allclose(features.roughness[inner], math.hypot(0.3, 0.2) * math.sqrt((dx ** 2).mean()))
    assert features.step_height.max() == 0.0
    # A 38 deg ramp is not a step: its rise over run stays under the critical slope.
    assert body_features(0.78 * x, RES).step_height.max() == 0.0
    # Flat ground costs nothing.
    flat = body_features(np.zeros((40, 40)), RES)
    assert np.all(body_cost(flat) == 0.0)


def test_step_edge_sets_step_height_and_traversability():
    x, _ = _grid((40, 80))
    z = np.where(x > 2.0, 0.15, 0.0)
    features = body_features(z, RES)
    reach = features.config.radius + features.config.step_window
    near = np.abs(x - 2.025) < reach - 0.1
    far = np.abs(x - 2.025) > reach + 0.05
    assert np.allclose(features.step_height[near], 0.15)
    assert np.all(features.step_height[far] == 0.0)
    assert traversable(features.step_height, 0.2).all()
    cost = body_cost(features, BodyCostConfig(max_step_height=0.1))
    assert np.all(np.isinf(cost[near])) and np.all(np.isfinite(cost[far]))
    # Fewer steep cells than n_crit scale the step down (a short edge is less of a step).
    lone = np.zeros((30, 30))
    lone[15, 15] = 0.15
    spike = body_features(lone, RES, config=BodyFeatureConfig(critical_count=1000)).step_height
    assert 0.0 < spike.max() < 0.15 * 30 / 1000


def test_body_cost_normalisation():
    x, _ = _grid((40, 40))
    features = body_features(np.where(x > 1.0, 0.15, 0.0), RES)
    config = BodyCostConfig(max_slope=1e-3, max_roughness=1e-3, max_step_height=0.15)
    cost = body_cost(features, config)
    steps = features.step_height == 0.15
    tilted = (features.slope > 1e-3) & (features.roughness > 1e-3)
    assert (steps & tilted).sum() > 100 and (steps & ~tilted).sum() > 10
    # Every feature at or over its maximum: the weighted norm with sum(w^2) = 1 gives exactly 1.
    assert np.allclose(cost[steps & tilted], 1.0)
    # Only the step (its disc misses the edge, its window does not): the step weight, 1/3.
    assert np.allclose(cost[steps & (features.slope < 1e-9)], 1.0 / 3.0)
    assert np.all(cost[np.isfinite(cost)] <= 1.0 + 1e-12)
    only_slope = body_cost(features, BodyCostConfig(weights=[3.0, 0.0, 0.0], max_slope=1.0, max_step_height=1.0))
    assert np.allclose(only_slope, np.minimum(features.slope, 1.0))
    with pytest.raises(TerrainError, match=r"^body_cost.weights = \[1.0, -1.0, 0.0\]"):
        body_cost(features, BodyCostConfig(weights=[1.0, -1.0, 0.0]))
    with pytest.raises(TerrainError, match=r"^body_cost.max_roughness = 0"):
        body_cost(features, BodyCostConfig(max_roughness=0))


def test_inputs_and_errors(rough_terrain):
    terrain = HeightMap(rough_terrain, RES, origin=(1.0, 2.0))
    from_map = body_features(terrain, config=BodyFeatureConfig(radius=0.2))
    from_array = body_features(rough_terrain, RES, config=BodyFeatureConfig(radius=0.2))
    assert np.array_equal(from_map.slope, from_array.slope)
    bad = rough_terrain.copy()
    bad[3, 4] = np.nan
    with pytest.raises(TerrainError, match=r"^heights\[3, 4\] = nan"):
        body_features(bad, RES)
    with pytest.raises(TerrainError, match=r"^resolution = None"):
        body_features(rough_terrain)
    with pytest.raises(TerrainError, match=r"^body_features.radius = 0.02"):
        body_features(rough_terrain, RES, config=BodyFeatureConfig(radius=0.02))
    with pytest.raises(TerrainError, match=r"^foothold_features.radii"):
        foothold_features(rough_terrain, RES, config=FootholdFeatureConfig(radii=[0.1]))
    with pytest.raises(TerrainError, match=r"^footprint.offsets"):
        Footprint(("a", "b"), np.zeros((3, 2)))


def test_foothold_features_match_cell_by_cell_definitions(rough_terrain):
    z = rough_terrain
    features = foothold_features(z, RES)
    for row, col in [(0, 0), (15, 14), (11, 20), (25, 30)]:
        for i, radius in enumerate(features.config.radii):
            dx, dy, h = _disc_cells(z, row, col, radius).T
            covariance = np.cov(np.stack([dx, dy, h]), bias=True)
            eig = np.linalg.eigvalsh(covariance)
            assert features.curvature[i, row, col] == pytest.approx(eig[0] / eig.sum(), abs=1e-8)
            (a, b, _), *_ = np.linalg.lstsq(np.stack([dx, dy, np.ones_like(dx)], axis=1), h, rcond=None)
            assert features.slope[i, row, col] == pytest.approx(math.atan(math.hypot(a, b)), abs=1e-9)
            normal = np.array([-a, -b, 1.0]) / math.sqrt(a * a + b * b + 1)
            angles = []
            for k in range(8):
                ox = round(radius / RES * math.cos(k * math.pi / 4))
                oy = round(radius / RES * math.sin(k * math.pi / 4))
                q = z[min(max(row + oy, 0), z.shape[0] - 1), min(max(col + ox, 0), z.shape[1] - 1)]
                v = np.array([ox * RES, oy * RES, q - z[row, col]])
                angles.append(math.acos(np.clip(v @ normal / np.linalg.norm(v), -1, 1)))
            assert features.convexity[i, row, col] == pytest.approx(np.mean(angles) - math.pi / 2, abs=1e-9)
            # Uphill along +y: arctan of the plane's rise that way.
            assert features.uphill(math.pi / 2)[i, row, col] == pytest.approx(math.atan(b), abs=1e-9)


def test_foothold_shapes_and_roles():
    x, y = _grid((41, 41))
    r2 = (x - 1.0) ** 2 + (y - 1.0) ** 2
    bump = foothold_features(-0.5 * r2, RES)
    bowl = foothold_features(0.5 * r2, RES)
    assert np.all(bump.convexity[:, 20, 20] > 0.01) and np.all(bowl.convexity[:, 20, 20] < -0.01)
    ramp = foothold_features(0.2 * x, RES)
    inner = (slice(None), slice(4, -4), slice(4, -4))  # the border plateau bends the ramp
    assert np.allclose(ramp.curvature[inner], 0.0, atol=1e-12) and np.allclose(ramp.convexity[inner], 0.0, atol=1e-9)
    assert np.allclose(ramp.uphill(0.0)[inner], math.atan(0.2))
    assert np.allclose(ramp.uphill(math.pi)[inner], -math.atan(0.2))
    # Walking up the ramp suits a front foot, down it a hind foot; a level foot sees no slope cost.
    front_up, hind_up = foothold_cost(ramp, 0.0, +1)[inner[1:]], foothold_cost(ramp, 0.0, -1)[inner[1:]]
    assert np.all(front_up < hind_up)
    assert np.allclose(foothold_cost(ramp, math.pi, +1)[inner[1:]], hind_up)
    flat = foothold_features(np.zeros((20, 20)), RES)
    assert np.all(foothold_cost(flat, 1.0, +1) == 0.0)
    costs = foothold_cost(bump, 0.3, -1, FootholdCostConfig())
    assert costs.min() >= 0.0 and costs.max() <= 1.0


def test_triangle_mask_geometry():
    side = 0.2
    mask = triangle_mask(side, RES)
    assert mask.shape == (7, 7) and mask[3, 3]
    assert mask.sum() == pytest.approx(math.sqrt(3) / 4 * side ** 2 / RES ** 2, rel=0.35)
    assert mask[3, 5] and not mask[3, 1]  # apex ahead (+x), base behind
    turned = triangle_mask(side, RES, math.pi / 2)
    assert turned[5, 3] and not turned[1, 3]  # apex along +y (rows)


@pytest.mark.parametrize("footprint", [Footprint.quadruped(0.4, 0.3), Footprint.qingzhui()], ids=["quadruped", "hexapod"])
def test_feet_cost_puts_each_foot_at_its_rotated_default_foothold(footprint):
    z = np.zeros((101, 101))
    z[50, 50] = 0.1  # one spike: foothold features are non-zero only within r2 + a cell of it
    features = foothold_features(z, RES)
    costs = feet_cost(features, footprint)
    assert costs.shape == (8, 101, 101) and costs.min() >= 0.0
    assert np.all(feet_cost(foothold_features(np.zeros((30, 30)), RES), footprint) < 1e-12)
    for k in (0, 2, 3):
        offsets = footprint.rotated(k * math.pi / 4)
        for x, y in offsets:
            body = (50 - int(round(y / RES)), 50 - int(round(x / RES)))
            assert costs[k][body] > 1e-3, (k, x, y)
        # A body centred on the spike has none of its feet near it.
        assert costs[k, 50, 50] < 1e-12  # FFT round-off only
    assert footprint.rotated(math.pi / 2)[0] == pytest.approx([-footprint.offsets[0, 1], footprint.offsets[0, 0]])


def test_cost_map_on_the_real_grid_map_terrain():
    terrain = grid_map_terrain(resolution=0.05, min_height=0.0, max_height=0.4)
    cost_map = build_cost_map(terrain, config=CostMapConfig(body_weight=0.6))
    assert cost_map.shape == (500, 500) and cost_map.origin == terrain.origin
    assert 0.0 <= cost_map.body.step_height.min() and cost_map.body.step_height.max() <= 0.4 + 1e-9
    # Between the 0.4 m blocks the body cannot go; on the flat stripe across the middle it can.
    assert not cost_map.traversable[325, 25] and not cost_map.traversable[340, 80]
    assert cost_map.traversable[250, 200:300].all() and cost_map.body_cost[250, 250] < 0.05
    assert 0.5 < cost_map.traversable.mean() < 0.85
    total = cost_map.heading_cost()
    finite = np.isfinite(total)
    assert total.shape == (8, 500, 500) and np.array_equal(finite, np.broadcast_to(cost_map.traversable, total.shape))
    assert total[finite].min() >= 0.0 and total[finite].max() <= 1.0
    row, col = cost_map.cell(*cost_map.xy([[250, 300]])[0])
    assert (row, col) == (250, 300)


def test_config_round_trips_through_yaml():
    from pydrake.common.yaml import yaml_dump_typed, yaml_load_typed

    config = CostMapConfig()
    config.body_cost.weights = [1.0, 1.0, 1.0]
    config.foothold_features.radii = [0.1, 0.2]
    text = yaml_dump_typed(config, defaults=CostMapConfig())
    assert "body_features" not in text  # only what differs is written
    assert yaml_load_typed(schema=CostMapConfig, data=text) == config
