"""CapPlanner's top-level controller as a system: plans around what the capability model calls
impossible, hands out missions one by one, replans at each mission start, says when the goal
is unreachable; and (slow) the whole CapPlanner walks a world in Drake."""

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import ConstantValueSource, ConstantVectorSource

from qz_drake.planning.capability_mdp import CapabilityMdpConfig
from qz_drake.systems.capability_planner import CapabilityVIPlanner
from qz_drake.systems.state_layout import make_state
from qz_drake.terrain import HeightMap

START, GOAL = (-3.0, 0.0), (3.0, 0.0)


class WallModel:
    """A capability model stub: a move whose patch holds ground 0.15 m above the standing
    ground fails (p = 0.02), any other succeeds (0.97); turns 0.99."""

    def success(self, patches, feet, kind, topology, direction=None):
        patches = np.asarray(patches)
        if kind == "turn":
            return np.full(patches.shape[:-2], 0.99)
        return np.where(patches.max(axis=(-2, -1)) > 0.15, 0.02, 0.97)


def _world(enclosed: bool = False) -> HeightMap:
    """8 m x 7 m of 0.05 m cells (x -4..4, y -3..4); a 0.4 m wall across x 0-0.5 m from
    y = -3 to 1 m (the way round is north of it, where a move's 2 m x 2 m patch no longer
    sees the wall from y = 2 m on), or, enclosed, a wall all round the goal."""
    res = 0.05
    c = -4.0 + res / 2 + res * np.arange(160)
    r = -3.0 + res / 2 + res * np.arange(140)
    gx, gy = np.meshgrid(c, r)
    heights = np.zeros(gx.shape)
    if enclosed:
        ring = (np.abs(gx - GOAL[0]) < 1.2) & (np.abs(gy - GOAL[1]) < 1.2)
        inner = (np.abs(gx - GOAL[0]) < 0.9) & (np.abs(gy - GOAL[1]) < 0.9)
        heights[ring & ~inner] = 0.4
    else:
        heights[(gx >= 0.0) & (gx < 0.5) & (gy < 1.0)] = 0.4
    return HeightMap(heights, res, (float(c[0]), float(r[0])))


def _planner(heightmap):
    return CapabilityVIPlanner(model=WallModel(), heightmap=heightmap, goal=GOAL, start=(*START, 0.0),
                               mdp_config=CapabilityMdpConfig(topologies=["nominal"]))


def test_the_first_plan_goes_round_the_wall_and_reaches_the_goal():
    planner = _planner(_world())
    assert not planner.log.unreachable
    (t, start, count, probability), = planner.log.replans
    assert start == (*START, 0, "nominal") and count >= 3 and probability > 0.5
    builder = DiagramBuilder()
    system = builder.AddSystem(planner)
    state = builder.AddSystem(ConstantVectorSource(make_state([*START, 0.55], [0, 0, 0], np.zeros(18))))
    plan = builder.AddSystem(ConstantValueSource(AbstractValue.Make(None)))
    builder.Connect(state.get_output_port(), system.GetInputPort("state"))
    builder.Connect(plan.get_output_port(), system.GetInputPort("plan"))
    diagram = builder.Build()
    context = diagram.CreateDefaultContext()
    sub = system.GetMyContextFromRoot(context)
    missions = system.GetOutputPort("guidance").Eval(sub)
    targets = np.array([m.target[:2] for m in missions])
    # The route passes north of the wall: every mission end within 1 m of it (in x) lies at
    # y >= 2 m, where the moves' patches no longer see it; the last one is the goal itself.
    near = np.abs(targets[:, 0] - 0.25) <= 1.0
    assert near.any() and np.all(targets[near, 1] >= 2.0 - 1e-9)
    np.testing.assert_allclose(targets[-1], GOAL)
    first = system.GetOutputPort("target").Eval(sub)
    np.testing.assert_allclose(first, missions[0].target)
    assert system.GetOutputPort("topology").Eval(sub) == "nominal"
    V, xs, ys = system.GetOutputPort("utility").Eval(sub)
    assert V.shape == (len(ys), len(xs))


def test_a_goal_behind_walls_is_reported_unreachable():
    planner = _planner(_world(enclosed=True))
    assert "predicted success" in planner.log.unreachable or "no path" in planner.log.unreachable
    assert planner.done
