"""torch's threads follow the free cores (qz_drake/threads.py), or QZ_TORCH_THREADS."""

import os

import pytest

from qz_drake import threads
from qz_drake.errors import QzError


def test_free_cores_leave_out_the_busy_ones(monkeypatch, tmp_path):
    """The cores less the tasks running elsewhere now (the reader not counted); the load
    average where the kernel gives no count."""
    monkeypatch.setattr(threads, "available_cores", lambda: 4)
    monkeypatch.setattr(os, "getloadavg", lambda: (3.5, 3.5, 3.5))  # a minute of past work: not now
    line = tmp_path / "loadavg"
    monkeypatch.setattr(threads, "LOADAVG", str(line))
    monkeypatch.setattr(threads, "RUNNING_MAX_AGE", 0.0)  # every call counts afresh
    for running, free in ((1, 4), (2, 3), (4, 1), (12, 1)):
        line.write_text(f"3.50 2.00 1.00 {running}/312 4242\n")
        assert threads.running_elsewhere() == running - 1
        assert threads.free_cores() == free, running
    monkeypatch.setattr(threads, "LOADAVG", str(tmp_path / "absent"))
    assert threads.running_elsewhere() is None
    for load, free in ((0.0, 4), (0.4, 4), (1.2, 3), (2.6, 1), (9.0, 1)):
        monkeypatch.setattr(os, "getloadavg", lambda load=load: (load, load, load))
        assert threads.free_cores() == free, load
    # A count is reused for RUNNING_MAX_AGE seconds: a plan asks at each of its steps.
    monkeypatch.setattr(threads, "RUNNING_MAX_AGE", 60.0)
    monkeypatch.setattr(threads, "LOADAVG", str(line))
    line.write_text("0.1 0.1 0.1 2/300 1\n")
    assert threads.running_elsewhere() == 1
    line.write_text("0.1 0.1 0.1 5/300 1\n")
    assert threads.running_elsewhere() == 1


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


def test_the_device_is_the_cpu_unless_asked_and_a_missing_one_is_refused_by_name(monkeypatch):
    """Capability inference runs on the CPU unless --device or QZ_TORCH_DEVICE asks for CUDA; a
    CUDA device torch does not see is one line naming the field (this machine has none: the
    check on a GPU is the device machine's)."""
    import torch

    monkeypatch.delenv(threads.DEVICE_VARIABLE, raising=False)
    assert threads.torch_device() == "cpu" and threads.torch_device("CPU") == "cpu"
    cuda = torch.cuda.device_count() if torch.cuda.is_available() else 0
    assert threads.torch_device("auto") == ("cuda" if cuda else "cpu")
    with pytest.raises(QzError, match="--device = 'gpu'"):
        threads.torch_device("gpu")
    monkeypatch.setenv(threads.DEVICE_VARIABLE, "cuda:x")
    with pytest.raises(QzError, match="QZ_TORCH_DEVICE = 'cuda:x'"):
        threads.torch_device()
    if not cuda:
        with pytest.raises(QzError, match="--device = 'cuda'.*sees 0 CUDA device"):
            threads.torch_device("cuda")
        monkeypatch.setenv(threads.DEVICE_VARIABLE, "cuda")
        with pytest.raises(QzError, match="QZ_TORCH_DEVICE = 'cuda'"):
            from qz_drake.capability.model import CapabilityModel

            CapabilityModel.random(seed=0)


def test_a_model_answers_the_same_wherever_it_runs(monkeypatch):
    """The networks on the device torch_device picks (the CPU here; a CUDA device where there
    is one) answer what they answer on the CPU, through success and the stacked map."""
    import numpy as np

    from qz_drake.capability.model import CapabilityModel

    monkeypatch.delenv(threads.DEVICE_VARIABLE, raising=False)
    cpu = CapabilityModel.random(seed=1)
    device = threads.torch_device("auto")
    there = CapabilityModel.random(seed=1).to(device)
    assert cpu.device == "cpu" and there.device == device
    rng = np.random.default_rng(0)
    patches = rng.normal(0.0, 0.05, (7, 20, 20))
    feet = rng.normal(0.0, 0.3, (7, 6, 3))
    np.testing.assert_allclose(there.success(patches, feet, "orthogonal", "nominal"),
                               cpu.success(patches, feet, "orthogonal", "nominal"), atol=1e-5)
    a = cpu.success_all(patches, {"nominal": feet, "split_up": feet}, "turn")
    b = there.success_all(patches, {"nominal": feet, "split_up": feet}, "turn")
    for t in a:
        np.testing.assert_allclose(b[t][0], a[t][0], atol=1e-5)
