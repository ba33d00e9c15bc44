"""The whole TLC plan (issue 14; paper 000 III-B: about 60 iterations in 23.47 s on 20 m x 20 m):
the capability of every forward move and turn from every cell and heading in all six topologies
(patch sampling and the networks), the MDP, value iteration and the most likely path, on the
20 m x 20 m long_range world and on 100 m x 100 m (five long_range worlds of other seeds tiled),
from a corner to the opposite one. Median of ``repeats``.

The networks are the shipped model's (qz_drake/data/capability_model), or seeded random weights
(CapabilityModel.random) where none ships. The networks' time does not depend on the weights;
value iteration's iteration count does: with random weights most moves fail (p near 0.5) and
the failure state absorbs the values within a few iterations; with the trained model most moves
succeed (p 0.9-0.99), Eq. 9 alone converged at about gamma * p per iteration (~700 iterations on
both worlds), and the solver's policy evaluation between improvements takes 24 on the 20 m world
and ~50 on 100 m (capability_mdp.solve_capability_mdp).
"""

import statistics
import time

import numpy as np


def _world(size: int):
    from qz_drake.terrain import HeightMap, make_terrain

    tile = make_terrain("long_range", seed=0)
    if size <= 20:
        return tile
    n = int(round(size / 20))
    rows = [np.hstack([make_terrain("long_range", seed=1 + i * n + j).heights for j in range(n)]) for i in range(n)]
    return HeightMap(np.vstack(rows), tile.resolution, tile.origin)


def run(repeats: int = 5, quick: bool = False, sizes=(20, 100)) -> dict:
    import torch

    from qz_drake.capability.model import CapabilityModel, predict_map
    from qz_drake.planning.capability_mdp import CapabilityMdpConfig, plan_on_map

    torch.set_num_threads(1)
    if quick:
        repeats, sizes = 1, (20,)
    from qz_drake.capability.model import DEFAULT_MODEL_DIR, MODEL_CARD

    if (DEFAULT_MODEL_DIR / MODEL_CARD).is_file():
        model = CapabilityModel.load()
        weights = f"the shipped model (dataset fingerprint {model.fingerprint})"
    else:
        model = CapabilityModel.random(seed=0)
        weights = "random (CapabilityModel.random, seed 0): timing only"
    out = {"weights": weights, "torch_threads": 1}
    if getattr(model, "card", {}).get("learner") == "boosted":
        from qz_drake.capability.boosted import inference_threads

        out["tree_threads"] = inference_threads()  # the free cores (QZ_TORCH_THREADS sets it)
    for size in sizes:
        heightmap = _world(size)
        xmin, xmax, ymin, ymax = heightmap.bounds
        start, goal = (xmin + 1.0, ymin + 1.0), (xmax - 1.0, ymax - 1.0)
        times, predict, iterations, states = [], [], [], 0
        for _ in range(repeats):
            clock = time.perf_counter()
            capability = predict_map(model, heightmap, anchor=start)
            middle = time.perf_counter()
            result = plan_on_map(capability, start, 1, goal, config=CapabilityMdpConfig())
            times.append(time.perf_counter() - clock)
            predict.append(middle - clock)
            iterations.append(int(result.solution.iterations))
            states = int(result.mdp.goal_state + 2)
        out[f"{size}m"] = {"plan_s_median": statistics.median(times), "plan_s": times,
                           "capability_map_s_median": statistics.median(predict),
                           "mdp_vi_path_s_median": statistics.median([t - p for t, p in zip(times, predict)]),
                           "vi_iterations": iterations, "states": states,
                           "reaches_goal": bool(result.reaches_goal), "path_actions": len(result.steps),
                           "predicted_fall_free": float(result.fall_free_probability)}
    return out
