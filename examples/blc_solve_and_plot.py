"""One BLC solve: Qingzhui's body and feet over two stairs, planned by trajectory optimisation.

The BLC (paper 000 Eq. 1-6) is a nonlinear program on Drake's MathematicalProgram, solved by
Ipopt: a ``BlcTask`` says where to go (a local target x, y, yaw) and in how long; ``solve_blc``
returns a ``BlcSolution``, a verdict (``success``, Ipopt's status, a dense check of every
constraint at 100 Hz) and the trajectories as Drake ``PiecewisePolynomial``s: the CoM position
and body roll-pitch-yaw, and per foot its position and ground reaction force. The example
samples them with ``vector_values`` and draws the body and feet with matplotlib, side view
over the terrain and heights against time.

Run (writes blc_stairs.png under --out; as ``qz blc --terrain stairs``, in Python):

    .venv/bin/python examples/blc_solve_and_plot.py [--distance 1.5] [--rise 0.1] [--out DIR]
"""

import argparse
import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")  # files only: no window
import matplotlib.pyplot as plt
import numpy as np

from qz_drake.config import TerrainConfig
from qz_drake.robot.params import LEG_NAMES
from qz_drake.scene import make_heightmap
from qz_drake.trajopt.robot_model import qingzhui
from qz_drake.trajopt.solver import BlcTask, solve_blc


def plot_body_and_feet(solution, path: Path) -> Path:
    """Side view (x, z) of the CoM and the feet over the terrain, and heights against time."""
    t = np.linspace(0.0, solution.duration, 201)
    com = solution.body_position.vector_values(t)  # (3, len(t))
    feet = [foot.vector_values(t) for foot in solution.foot_positions]
    contact = solution.contact(t)  # (len(t), legs)

    fig, (side, heights) = plt.subplots(2, 1, figsize=(10, 8))
    x = np.linspace(com[0].min() - 0.8, com[0].max() + 0.8, 300)
    side.fill_between(x, solution.terrain.height(x, np.zeros_like(x)), -0.05, color="0.8", label="terrain (y = 0)")
    side.plot(com[0], com[2], "k", lw=2, label="CoM")
    for leg, (foot, name) in enumerate(zip(feet, LEG_NAMES)):
        line, = side.plot(foot[0], foot[2], lw=1, label=name)
        # Footholds: where the foot is in contact.
        side.plot(foot[0, contact[:, leg]], foot[2, contact[:, leg]], ".", color=line.get_color(), ms=3)
        heights.plot(t, foot[2], color=line.get_color(), lw=1, label=name)
    heights.plot(t, com[2], "k", lw=2, label="CoM")
    side.set(xlabel="x [m]", ylabel="z [m]", title="side view: CoM and feet (dots: in contact)", aspect="equal")
    heights.set(xlabel="t [s]", ylabel="z [m]", title="heights against time")
    side.legend(fontsize=8, ncol=4, loc="upper left")
    heights.legend(fontsize=8, ncol=7, loc="upper left")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--distance", type=float, default=1.5, help="target distance along x [m]")
    parser.add_argument("--rise", type=float, default=0.1, help="height of each stair [m]")
    parser.add_argument("--out", default="out/examples/blc_solve_and_plot", help="output folder")
    args = parser.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)

    # Two stairs up from x = 0.9 m; the robot stands at the origin facing +x.
    heightmap = make_heightmap(TerrainConfig(kind="stairs", params={"rise": args.rise, "run": 0.4, "count": 2,
                                                                     "start_x": 0.9}))
    # Slower than the nominal walking speed: stairs take care.
    task = BlcTask(target=(args.distance, 0.0, 0.0), topology="nominal", duration=round(1.0 + 2.0 * args.distance, 1))
    solution = solve_blc(task, qingzhui(task.topology), heightmap)
    print(f"BLC {'solved' if solution.success else 'FAILED'}: {solution.status}, {solution.iterations} iterations, "
          f"{solution.solve_time:.2f} s, largest violation {solution.max_violation:.1e}"
          + ("" if solution.success else f" ({solution.reason})"))
    end = solution.body_position.value(solution.duration).ravel()
    print(f"CoM from {solution.body_position.value(0.0).ravel().round(3)} to {end.round(3)} m "
          f"in {solution.duration:g} s")
    print(f"plot: {plot_body_and_feet(solution, out / 'blc_stairs.png')}")
    return 0 if solution.success else 1


if __name__ == "__main__":
    sys.exit(main())
