"""Fixtures shared across test folders."""

import sys

import pytest

# torch's intra-op threads when the tests were collected (tests/capability's modules set one).
_torch_threads = None


def pytest_collection_finish(session):
    global _torch_threads
    torch = sys.modules.get("torch")
    if torch is not None:
        _torch_threads = torch.get_num_threads()


@pytest.hookimpl(tryfirst=True)
def pytest_runtest_setup(item):
    """Each test, its fixtures included, starts with torch's threads as they were collected.
    Loading a capability model sets them to the free cores (qz_drake.threads) and training sets
    none, so a training test that came after a model load on a quiet moment trained with two
    threads: test_training.py's `learned` took 102 s in a loaded `make test` and 11 s alone
    (the same training, 93 s with two threads and 13 s with one, the other core busy)."""
    global _torch_threads
    torch = sys.modules.get("torch")
    if torch is None:
        return
    if _torch_threads is None:
        _torch_threads = torch.get_num_threads()
    elif torch.get_num_threads() != _torch_threads:
        torch.set_num_threads(_torch_threads)


def _train_synthetic_model(scenes: int, headings: int, max_epochs: int, patience: int):
    """(arrays, TrainingResult): the nominal topology's networks trained on synthetic trials whose
    label is a known rule (success when the patch's height range is at most 0.15 m), in
    ensembles of two (the planners read their spread; five would triple the training for no
    other test)."""
    import torch

    from qz_drake.capability.synthetic import synthetic_arrays
    from qz_drake.capability.training import TrainingConfig, train_networks

    torch.set_num_threads(1)
    arrays, manifest = synthetic_arrays(scenes=scenes, headings=headings)
    # No component fingerprints: the model describes no robot configuration, so the robot
    # check of CapabilityModel.load lets it through.
    result = train_networks(arrays, fingerprint=manifest["fingerprint"], fingerprints=None,
                            config=TrainingConfig(max_epochs=max_epochs, patience=patience, ensemble=2))
    assert sorted(result.networks) == [("nominal", "diagonal"), ("nominal", "orthogonal"), ("nominal", "turn")]
    return arrays, result


@pytest.fixture(scope="session")
def synthetic_model_dir(tmp_path_factory):
    """A capability model that has learned the synthetic rule (_train_synthetic_model): real
    CNNs, real files, for the planners' end-to-end tests with a model other than the shipped
    one (all of them slow; its training takes 30 s on the project's 2-core machine)."""
    import numpy as np
    import torch
    from sklearn.metrics import roc_auc_score

    from qz_drake.capability.model import save_model
    from qz_drake.capability.synthetic import synthetic_rule

    arrays, result = _train_synthetic_model(scenes=40, headings=12, max_epochs=40, patience=8)
    # The planners' tests rely on the three nominal networks having learned the rule on
    # held-out scenes: ranked against the rule itself (the labels have 3 % flipped, which caps
    # the AUC against them near 0.9 on these 72 test trials a network).
    test = np.isin(arrays["scene"], result.split["test"])
    for (_, kind), network in result.networks.items():
        rows = test & (arrays["kind"] == kind)
        extra = arrays["feet"][rows].reshape(-1, 18)
        if kind == "turn":
            extra = np.column_stack([extra, arrays["direction"][rows]]).astype(np.float32)
        with torch.no_grad():
            p = network.net.probability(torch.as_tensor(arrays["patch"][rows]), torch.as_tensor(extra)).numpy()
        assert roc_auc_score(synthetic_rule(arrays["patch"][rows]), p) > 0.95, (kind, network.card["test"])
    return save_model(result, tmp_path_factory.mktemp("synthetic_model"))


@pytest.fixture(scope="session")
def briefly_trained_model_dir(tmp_path_factory):
    """synthetic_model_dir's recipe trained for two epochs on 16 scenes (1-3 s): the same
    networks and files, not the rule learned, for the tests that need a saved model other than
    the shipped one and never how well it predicts (a results folder's model identity, the
    commands that take --model, goals refused before planning). Even a random model's plan
    from (0, 0) to (3, 0.5) on flat ground reaches the goal, as qz plan's test asks."""
    from qz_drake.capability.model import save_model

    _, result = _train_synthetic_model(scenes=16, headings=6, max_epochs=2, patience=2)
    return save_model(result, tmp_path_factory.mktemp("briefly_trained_model"))


class StraightPlan:
    """A walked mission's plan, as the BLC system's ``plan`` output gives it to a route
    sequencer: a straight walk from ``start`` to ``end`` (x, y) at yaw 0 and base height ``z``
    between times t0 and t1."""

    is_mission = True

    def __init__(self, start, end, t0, t1, z=0.55):
        import numpy as np

        self._start, self._end = np.asarray(start, float), np.asarray(end, float)
        self.start_time, self.end_time, self._z = float(t0), float(t1), float(z)

    def base_position(self, t):
        import numpy as np

        s = np.clip((t - self.start_time) / (self.end_time - self.start_time), 0.0, 1.0)
        return np.array([*(self._start + s * (self._end - self._start)), self._z])

    def base_rpy(self, t):
        import numpy as np

        return np.zeros(3)

    def foot_positions(self, t):
        """The nominal topology's footholds round the base on level ground (z = 0)."""
        import numpy as np

        from qz_drake.capability import patches as P
        from qz_drake.robot.params import DEFAULT_PARAMS
        from qz_drake.robot.topology import get_topology
        from qz_drake.terrain import HeightMap

        x, y, _ = self.base_position(t)
        flat = HeightMap(np.zeros((81, 81)), 0.05, (x - 2.0, y - 2.0))
        return P.nominal_feet_W(flat, x, y, 0.0, get_topology("nominal"), DEFAULT_PARAMS.foot_radius)


@pytest.fixture
def straight_plan():
    """StraightPlan, for tests of the sequencers that follow the BLC's plans."""
    return StraightPlan
