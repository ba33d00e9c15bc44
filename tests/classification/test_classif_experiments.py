"""Experiment scores of paper 002's mixed floor: the classifier's errors apart from the delay
of the three-confirmation rule; box-plot spreads."""

import numpy as np
import pytest

from qz_drake.classification.experiments import spread, stance_label_scores


def test_settled_accuracy_and_switch_latency_by_hand():
    # Leg 0: five stances on concrete (0), then five on foam (2); the confirmed label follows
    # three stances late and one settled foam stance is mislabelled wood (1).
    truth = [0, 0, 0, 0, 0, 2, 2, 2, 2, 2]
    label = [-1, -1, 0, 0, 0, 0, 0, 2, 1, 2]
    # Leg 1: concrete then wood, but the label never switches before the floor changes back.
    truth1 = [0, 0, 0, 1, 1, 0, 0, 0]
    label1 = [-1, -1, 0, 0, 0, 0, 0, 0]
    legs = [0] * len(truth) + [1] * len(truth1)
    scores = stance_label_scores(legs, truth + truth1, label + label1, confirmations=3)
    # Settled stances: leg 0 k = 2, 3, 4 (concrete) and 7, 8, 9 (foam); leg 1 k = 2 and 7.
    assert scores["settled_stances"] == 8
    # Wrong among them: leg 0 k = 8 (wood); k = 5, 6 (still concrete) are not settled.
    assert scores["settled_accuracy"] == pytest.approx(7 / 8)
    # Leg 0 switched to foam at its third foam stance; leg 1's switch to wood never came, and
    # its switch back to concrete was immediate (the label had stayed concrete).
    assert scores["switch_latency_stances"] == [3, 1]
    assert scores["missed_switches"] == 1
    assert scores["median_switch_latency_stances"] == 2.0


def test_unknown_ground_is_not_scored():
    scores = stance_label_scores([0, 0, 0, 0], [-1, -1, -1, -1], [0, 0, 0, 0])
    assert scores["settled_stances"] == 0 and scores["settled_accuracy"] is None
    assert scores["switch_latency_stances"] == [] and scores["median_switch_latency_stances"] is None


def test_spread_of_a_known_sample():
    values = np.arange(101.0)
    s = spread(values)
    assert s["iqr"] == pytest.approx(50.0) and s["p5_p95"] == pytest.approx(90.0)
    assert s["median"] == 50.0 and s["min"] == 0.0 and s["max"] == 100.0
