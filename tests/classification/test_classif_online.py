"""TerrainClassifier: stance segmentation from the gait state, skipped short stances, and
stiffness switching only after three confirmations (paper 002, section 4.3)."""

import numpy as np
import pytest
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import ConstantVectorSource, LogVectorOutput, TrajectorySource
from pydrake.trajectories import PiecewisePolynomial

from qz_drake.robot import kinematics
from qz_drake.robot.topology import get_topology
from qz_drake.station import standing_state
from qz_drake.classification.terrain_classifier import TerrainClassifier
from qz_drake.systems.trotting import LDS, LTS, THS, WAS
from qz_drake.terrain import make_terrain
from qz_drake.errors import ConfigError

DT = 0.002


class ThresholdModel:
    """A test double for one leg's SvmModel: foam when the first window's peak force is
    below 150 N, concrete otherwise."""

    classes = ("concrete", "wood", "foam")

    def predict_index(self, X):
        return np.where(np.asarray(X)[:, 0] < 150.0, 2, 0)


def _run(stances, models=None):
    """Leg MF steps through ``stances`` (vertical force [N], samples in support); the other
    legs hang in LDS. Returns logs of label, stiffness, prediction, counts."""
    x = standing_state(make_terrain("flat"), get_topology("nominal"))
    q = x[7:25]
    times, gait, torque = [0.0], [np.full(6, LDS)], [np.zeros(18)]
    t = 20 * DT
    for force, samples in stances:
        tau = np.zeros(18)
        tau[:3] = -kinematics.foot_jacobian(0, q[:3]).T @ np.array([0.0, 0.0, force])
        accept = min(10, samples)
        for state, n in ((WAS, accept), (THS, samples - accept), (LTS, 10), (LDS, 20)):
            if n <= 0:
                continue
            g = np.full(6, LDS)
            g[0] = state
            times.append(t)
            gait.append(g)
            torque.append(tau if state in (WAS, THS) else np.zeros(18))
            t += n * DT
    times.append(t)
    gait.append(np.full(6, LDS))
    torque.append(np.zeros(18))
    builder = DiagramBuilder()
    classifier = builder.AddSystem(TerrainClassifier(models=models, period=DT))
    # Sampled half a step after each switch, so a state lasts exactly its sample count.
    shifted = np.array(times) - DT / 2
    shifted[0] = 0.0
    for name, values in (("gait_state", gait), ("joint_torque_measured", torque)):
        source = builder.AddSystem(TrajectorySource(PiecewisePolynomial.ZeroOrderHold(shifted, np.array(values).T)))
        builder.Connect(source.get_output_port(), classifier.GetInputPort(name))
    imu = np.zeros(10)
    imu[0] = 1.0
    for name, value in (("state", x), ("imu", imu)):
        builder.Connect(builder.AddSystem(ConstantVectorSource(value)).get_output_port(), classifier.GetInputPort(name))
    logs = {name: LogVectorOutput(classifier.GetOutputPort(name), builder, DT)
            for name in ("terrain_label", "stiffness", "prediction", "stance_count", "skipped_stances",
                         "stance_features")}
    simulator = Simulator(builder.Build())
    simulator.AdvanceTo(t)
    return {name: log.FindLog(simulator.get_context()).data().T for name, log in logs.items()}


def test_switches_stiffness_after_three_confirmations_and_skips_short_stances():
    concrete, foam = 200.0, 100.0
    stances = [(concrete, 30)] * 3 + [(foam, 30), (concrete, 30), (foam, 4)] + [(foam, 30)] * 3
    logs = _run(stances, models=[ThresholdModel()] * 6)
    assert logs["stance_count"][-1, 0] == 8 and logs["skipped_stances"][-1, 0] == 1
    assert np.all(logs["stance_count"][-1, 1:] == 0)
    # The confirmed label and the stiffness change only at the third concrete stance...
    labels, stiffness, count = logs["terrain_label"][:, 0], logs["stiffness"][:, 0], logs["stance_count"][:, 0]
    assert np.all(labels[count < 3] == -1) and np.all(stiffness[count < 3] == 9000.0)
    assert np.all(labels[(count >= 3) & (count < 8)] == 0)
    assert np.all(stiffness[(count >= 3) & (count < 8)] == 7000.0)
    # ...a lone foam stance, interrupted by concrete, does not switch; the short stance
    # neither counts nor breaks the run of three foam stances that follows.
    assert labels[-1] == 2 and stiffness[-1] == 11000.0
    assert np.all(logs["stiffness"][-1, 1:] == 9000.0)
    # The features of the last stance: 30 samples of a constant 100 N.
    f = logs["stance_features"][-1].reshape(6, 18)[0]
    np.testing.assert_allclose(f[[0, 1, 2, 3, 5, 10]], foam, rtol=1e-9)
    np.testing.assert_allclose(f[[4, 9, 14]], 0.0, atol=1e-9)


def test_records_without_models():
    logs = _run([(180.0, 40), (120.0, 40)])
    assert logs["stance_count"][-1, 0] == 2
    assert np.all(logs["terrain_label"] == -1) and np.all(logs["stiffness"] == 9000.0)
    assert logs["stance_features"][-1, 0] == pytest.approx(120.0)


def test_bad_models_are_named():
    with pytest.raises(ConfigError, match="models"):
        TerrainClassifier(models=[ThresholdModel()] * 5)
    with pytest.raises(ConfigError, match="stiffness_by_material.foam"):
        TerrainClassifier(stiffness_by_material={"foam": -1.0})
