"""torch's threads follow the free cores (qz_drake/threads.py), or QZ_TORCH_THREADS."""

import os

import pytest

from qz_drake import threads
from qz_drake.errors import QzError


def test_free_cores_leave_out_the_busy_ones(monkeypatch):
    monkeypatch.setattr(threads, "available_cores", lambda: 4)
    for load, free in ((0.0, 4), (0.4, 4), (1.2, 3), (2.6, 1), (9.0, 1)):
        monkeypatch.setattr(os, "getloadavg", lambda load=load: (load, load, load))
        assert threads.free_cores() == free, load


def test_the_variable_sets_the_threads_and_bad_values_name_it(monkeypatch):
    monkeypatch.setenv(threads.ENV_VARIABLE, "3")
    assert threads.torch_threads() == 3
    for bad in ("0", "-1", "two", "1.5"):
        monkeypatch.setenv(threads.ENV_VARIABLE, bad)
        with pytest.raises(QzError, match=f"QZ_TORCH_THREADS.*{bad}"):
            threads.torch_threads()


def test_loading_a_model_sets_torchs_threads(monkeypatch):
    import torch

    from qz_drake.capability.model import CapabilityModel

    before = torch.get_num_threads()
    try:
        monkeypatch.setenv(threads.ENV_VARIABLE, "1")
        CapabilityModel.random(topologies=["nominal"], kinds=("turn",))
        assert torch.get_num_threads() == 1
    finally:
        torch.set_num_threads(before)
