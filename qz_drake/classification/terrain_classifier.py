"""Online terrain classification and stiffness switching per leg (paper 002, sections 3 and 4.3).

Every control period each supporting leg (gait state WAS or THS, from a landing to its
lift-off) samples its vertical foot force from the measured joint torques (Eq. 6), the body's
pitch and roll from the IMU and its foot speed. When the stance ends the leg's 18 features
(Eq. 7-8) go to the leg's own SVM; a leg switches to a new terrain, and to that terrain's
stance stiffness, only after the SVM has named it three stances in a row. A stance too short
for three feature windows is skipped and counted.

Without models the system only records: each finished stance's features are held on the
``stance_features`` port (with ``stance_count``) until the leg's next stance ends, which is how
``qz classify collect`` gathers its dataset with exactly the online code path.
"""

from __future__ import annotations

import numpy as np
from pydrake.systems.framework import LeafSystem

from qz_drake.classification import features as feat
from qz_drake.errors import bad_value
from qz_drake.robot.params import DEFAULT_PARAMS, NUM_LEGS, QingzhuiParams
from qz_drake.state_layout import IMU_SIZE, JOINT_Q, JOINT_V, STATE_SIZE
from qz_drake.systems.trotting import THS, WAS

# Paper 002, section 5: default stance stiffness and the two presets. [N/m]
DEFAULT_STIFFNESS = 9000.0
STIFFNESS_BY_MATERIAL = {"concrete": 7000.0, "foam": 11000.0}
# Stances in a row that must name a new terrain before a leg switches to it.
CONFIRMATIONS = 3
UNKNOWN = -1


class TerrainClassifier(LeafSystem):
    """Per-leg stance features, SVM classification and stiffness commands.

    .. pydrake_system::

        name: TerrainClassifier
        input_ports:
        - state
        - joint_torque_measured
        - imu
        - gait_state
        output_ports:
        - terrain_label
        - stiffness
        - prediction
        - stance_features
        - stance_count
        - skipped_stances

    ``terrain_label`` (6) is each leg's confirmed terrain, an index into ``classes`` (-1 before
    any is confirmed); ``stiffness`` (6) the stance stiffness for the SphericalImpedance [N/m];
    ``prediction`` (6) the SVM's label of the leg's last stance (-1 none); ``stance_features``
    (6 x 18) the features of each leg's last classified stance; ``stance_count`` and
    ``skipped_stances`` (6) count finished stances with and without features.

    Args:
        models: one SvmModel per leg (qz_drake.classification.svm), or None to only record.
        classes: terrain names the labels index; default the models' classes.
        default_stiffness: stiffness of an unknown terrain and of terrains not in
            ``stiffness_by_material``. [N/m]
        stiffness_by_material: stiffness per terrain name. [N/m]
        confirmations: stances in a row needed to switch terrain.
        period: sampling and update period (the station's plant step). [s]
        params: robot parameters (leg kinematics for Eq. 6).
    """

    def __init__(self, *, models=None, classes: tuple[str, ...] | None = None,
                 default_stiffness: float = DEFAULT_STIFFNESS, stiffness_by_material: dict | None = None,
                 confirmations: int = CONFIRMATIONS, period: float = 0.002,
                 params: QingzhuiParams = DEFAULT_PARAMS):
        super().__init__()
        if models is not None and len(models) != NUM_LEGS:
            raise bad_value("models", f"{len(models)} models", f"expected one per leg ({NUM_LEGS})")
        if classes is None:
            classes = tuple(models[0].classes) if models is not None else ("concrete", "wood", "foam")
        self._classes = tuple(classes)
        if models is not None:
            for i, m in enumerate(models):
                unknown = [c for c in m.classes if c not in self._classes]
                if unknown:
                    raise bad_value(f"models[{i}].classes", list(m.classes), f"not in classes {self._classes}")
        if not (isinstance(confirmations, int) and confirmations >= 1):
            raise bad_value("confirmations", confirmations, "must be a positive integer")
        table = dict(STIFFNESS_BY_MATERIAL if stiffness_by_material is None else stiffness_by_material)
        for name, k in table.items():
            if not (np.isfinite(k) and k > 0):
                raise bad_value(f"stiffness_by_material.{name}", k, "must be a positive stiffness in N/m")
        self._models = models
        # Each model's class order -> this system's class index.
        self._class_maps = None if models is None else [
            np.array([self._classes.index(c) for c in m.classes]) for m in models]
        self._default = float(default_stiffness)
        self._stiffness_of = np.array([table.get(c, self._default) for c in self._classes])
        self._confirmations = confirmations
        self._params = params
        n = feat.MAX_STANCE_SAMPLES * feat.SAMPLE_SIZE
        self._x = self.DeclareVectorInputPort("state", STATE_SIZE)
        self._tau = self.DeclareVectorInputPort("joint_torque_measured", 18)
        self._imu = self.DeclareVectorInputPort("imu", IMU_SIZE)
        self._gait = self.DeclareVectorInputPort("gait_state", NUM_LEGS)
        self._buffer = self.DeclareDiscreteState(np.zeros(NUM_LEGS * n))
        # Per leg: samples so far, in stance (0/1).
        self._progress = self.DeclareDiscreteState(np.zeros(2 * NUM_LEGS))
        self._features = self.DeclareDiscreteState(np.zeros(NUM_LEGS * feat.NUM_FEATURES))
        self._counts = self.DeclareDiscreteState(np.zeros(2 * NUM_LEGS))
        # Per leg: confirmed label, candidate label, confirmations of the candidate, last prediction.
        self._labels = self.DeclareDiscreteState(np.tile([UNKNOWN, UNKNOWN, 0.0, UNKNOWN], NUM_LEGS))
        self._stiffness = self.DeclareDiscreteState(np.full(NUM_LEGS, self._default))
        self.DeclarePeriodicDiscreteUpdateEvent(period, 0.0, self._update)
        self.DeclareVectorOutputPort("terrain_label", NUM_LEGS, self._calc_label)
        self.DeclareStateOutputPort("stiffness", self._stiffness)
        self.DeclareVectorOutputPort("prediction", NUM_LEGS, self._calc_prediction)
        self.DeclareStateOutputPort("stance_features", self._features)
        self.DeclareVectorOutputPort("stance_count", NUM_LEGS,
                                     lambda c, o: o.SetFromVector(c.get_discrete_state(self._counts).value()[:6]))
        self.DeclareVectorOutputPort("skipped_stances", NUM_LEGS,
                                     lambda c, o: o.SetFromVector(c.get_discrete_state(self._counts).value()[6:]))

    @property
    def classes(self) -> tuple[str, ...]:
        return self._classes

    def _calc_label(self, context, output):
        output.SetFromVector(context.get_discrete_state(self._labels).value().reshape(NUM_LEGS, 4)[:, 0])

    def _calc_prediction(self, context, output):
        output.SetFromVector(context.get_discrete_state(self._labels).value().reshape(NUM_LEGS, 4)[:, 3])

    def classify(self, leg: int, features: np.ndarray) -> int:
        """The class index (into ``classes``) the leg's model gives one feature vector."""
        return int(self._class_maps[leg][self._models[leg].predict_index(features[None, :])[0]])

    def _update(self, context, discrete_state):
        x = self._x.Eval(context)
        gait = self._gait.Eval(context)
        supporting = (gait == WAS) | (gait == THS)
        progress = discrete_state.get_mutable_vector(self._progress).get_mutable_value().reshape(NUM_LEGS, 2)
        if not supporting.any() and not progress[:, 1].any():
            return
        buffer = discrete_state.get_mutable_vector(self._buffer).get_mutable_value().reshape(
            NUM_LEGS, feat.MAX_STANCE_SAMPLES, feat.SAMPLE_SIZE)
        features = discrete_state.get_mutable_vector(self._features).get_mutable_value().reshape(NUM_LEGS, -1)
        counts = discrete_state.get_mutable_vector(self._counts).get_mutable_value()
        labels = discrete_state.get_mutable_vector(self._labels).get_mutable_value().reshape(NUM_LEGS, 4)
        stiffness = discrete_state.get_mutable_vector(self._stiffness).get_mutable_value()
        sample = None
        for i in range(NUM_LEGS):
            in_stance = progress[i, 1] > 0.5
            if supporting[i] and (in_stance or gait[i] == WAS):
                # A stance starts at a landing (WAS): the standing start is not one.
                if sample is None:
                    sample = feat.measure(x[JOINT_Q], x[JOINT_V], self._tau.Eval(context), self._imu.Eval(context),
                                          self._params)
                n = int(progress[i, 0])
                if n < feat.MAX_STANCE_SAMPLES:
                    buffer[i, n] = sample[i]
                    progress[i, 0] = n + 1
                progress[i, 1] = 1.0
            elif in_stance:
                self._finish_stance(i, buffer[i, :int(progress[i, 0])], features, counts, labels, stiffness)
                progress[i] = 0.0

    def _finish_stance(self, leg, samples, features, counts, labels, stiffness):
        f = feat.stance_features(samples)
        if f is None:
            counts[NUM_LEGS + leg] += 1
            return
        features[leg] = f
        counts[leg] += 1
        if self._models is None:
            return
        predicted = self.classify(leg, f)
        confirmed, candidate, seen, _ = labels[leg]
        if predicted == confirmed:
            candidate, seen = UNKNOWN, 0
        elif predicted == candidate:
            seen += 1
        else:
            candidate, seen = predicted, 1
        if seen >= self._confirmations:
            confirmed, candidate, seen = predicted, UNKNOWN, 0
            stiffness[leg] = self._stiffness_of[int(confirmed)]
        labels[leg] = (confirmed, candidate, seen, predicted)
