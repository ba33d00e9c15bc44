"""The strict verdict: each check fails a walk with its reason code, in the documented order."""

import numpy as np
import pytest

from qz_drake.config import SuccessCriteria
from qz_drake.robot.topology import get_topology
from qz_drake.state_layout import make_state
from qz_drake.verdict import REASON_CODES, blc_failure_code, foot_slip, judge_walk

N = 200


def _clean_walk():
    times = np.arange(N) * 0.01
    q = get_topology("nominal").standing_pose()
    states = np.array([make_state([t * 0.5, 0.0, 0.55], [0, 0, 0], q) for t in times])
    feet = np.zeros((N, 6, 3))
    feet[:, :, 0] = np.arange(6)[None, :]
    return dict(goal_xy_yaw=(times[-1] * 0.5, 0.0, 0.0), times=times, states=states,
                desired_q=states[:, 7:25].copy(), feet_W=feet, contacts=np.ones((N, 6)),
                trunk=np.zeros(N), leg_link_force=np.zeros((N, 6)), self_force=np.zeros(N))


def test_a_clean_walk_succeeds():
    v = judge_walk(SuccessCriteria(), **_clean_walk())
    assert v.success and v.reasons == [] and v.reason == ""


def test_a_single_joint_spike_fails_tracking_although_the_rms_is_small():
    logs = _clean_walk()
    logs["desired_q"][120, 4] += np.radians(140)  # one sample of 18 x 200
    v = judge_walk(SuccessCriteria(), **logs)
    assert v.reasons == ["tracking"]
    assert "140 deg" in v.message and "t = 1.20 s" in v.message


@pytest.mark.parametrize("edit, code", [
    (lambda l: l["leg_link_force"].__setitem__((50, 2), 40.0), "leg_contact"),
    (lambda l: l["self_force"].__setitem__(10, 30.0), "leg_contact"),
    (lambda l: l["trunk"].__setitem__(10, 1.0), "trunk_contact"),
    (lambda l: l["feet_W"].__setitem__((slice(100, None), 3, 0), 3.08), "slip"),
    (lambda l: l.__setitem__("goal_xy_yaw", (0.0, 0.5, 0.0)), "missed_target"),
    (lambda l: l.__setitem__("goal_xy_yaw", (l["goal_xy_yaw"][0], 0.0, 0.5)), "missed_target"),
])
def test_each_check_names_its_reason(edit, code):
    logs = _clean_walk()
    edit(logs)
    v = judge_walk(SuccessCriteria(), **logs)
    assert not v.success and v.reasons == [code], v.messages


def test_reasons_are_ordered_and_blc_failures_classified():
    logs = _clean_walk()
    logs["trunk"][5] = 1.0
    v = judge_walk(SuccessCriteria(), **logs, blc_failures=["mission 1: BLC: Ipopt: Wall time exceeded"],
                   fell=True)
    assert v.reasons == ["blc_time_limit", "fell", "trunk_contact"]
    assert [REASON_CODES.index(r) for r in v.reasons] == sorted(REASON_CODES.index(r) for r in v.reasons)
    assert blc_failure_code("BLC: Ipopt: Infeasible_Problem_Detected") == "blc_infeasible"
    assert blc_failure_code("BLC: max violation 0.2; time limit 5 s") == "blc_time_limit"


def test_foot_slip_measures_each_contact_from_its_own_start():
    feet = np.zeros((6, 6, 3))
    feet[:, 0, 0] = [0.0, 0.01, 0.5, 0.5, 0.52, 0.53]
    contacts = np.ones((6, 6))
    contacts[2, 0] = 0  # a swing between two stances: the 0.5 m move is not a slip
    slip = foot_slip(feet, contacts)
    assert slip[0] == pytest.approx(0.03)
