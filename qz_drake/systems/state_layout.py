"""The station state's layout, now qz_drake.state_layout: kept under its old name only for
the modules another change is rewriting at the same time (systems/joint_pd.py,
hardware/driver.py, hardware/interface.py); it goes once they import qz_drake.state_layout."""

from qz_drake.state_layout import (BASE_ANGVEL, BASE_POS, BASE_QUAT, BASE_VEL, BASE_XY, BASE_Z,  # noqa: F401
                                   IMU_SIZE, JOINT_Q, JOINT_V, NUM_Q, NUM_V, STATE_SIZE, base_pose, base_rpy,
                                   make_state, tilt_deg)
