"""Sensor systems of the simulated station: foot contact from contact results and the IMU."""

from __future__ import annotations

import numpy as np
from pydrake.multibody.plant import ContactResults, MultibodyPlant
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import BasicVector, LeafSystem, ValueProducer

from qz_drake.robot.params import LEG_NAMES
from qz_drake.state_layout import IMU_SIZE


class FootContactSensor(LeafSystem):
    """Which feet touch the terrain, and whether the trunk or a leg link does, from the plant's
    contact results.

    A foot counts as in contact when the normal force on it exceeds ``force_threshold``. Leg
    links (thighs and shanks) touching the terrain are reported apart from the feet: paper 000
    Fig. 2's failure, a shank on a stair edge, is a contact a walk must not have.

    .. pydrake_system::

        name: FootContactSensor
        input_ports:
        - contact_results
        output_ports:
        - foot_contact
        - foot_normal_force
        - trunk_contact
        - leg_link_force
        - self_contact

    ``leg_link_force`` (6) is the force of the terrain on each leg's thigh and shank [N];
    ``self_contact`` (1) the largest force between two of the robot's own bodies (legs of
    different hips) [N].

    Args:
        plant: the station's plant (finalized), used to map bodies to feet.
        instance: Qingzhui's model instance.
        force_threshold: smallest normal force that counts as contact. [N]
    """

    def __init__(self, *, plant: MultibodyPlant, instance, force_threshold: float = 5.0):
        super().__init__()
        self._threshold = force_threshold
        self._foot_of_body = {}
        self._leg_of_link = {}
        for i, leg in enumerate(LEG_NAMES):
            self._foot_of_body[int(plant.GetBodyByName(f"{leg}_foot", instance).index())] = i
            for link in ("thigh", "shank"):
                self._leg_of_link[int(plant.GetBodyByName(f"{leg}_{link}", instance).index())] = i
        self._trunk = int(plant.GetBodyByName("base", instance).index())
        self._robot_bodies = {int(b) for b in plant.GetBodyIndices(instance)}
        # Hydroelastic results name geometries, not bodies.
        self._body_of_geometry = {}
        for b in plant.GetBodyIndices(instance):
            for g in plant.GetCollisionGeometriesForBody(plant.get_body(b)):
                self._body_of_geometry[g] = int(b)
        self._contact_port = self.DeclareAbstractInputPort("contact_results",
                                                           plant.get_contact_results_output_port().Allocate())
        # The five outputs share one pass over the contact results, cached per context until
        # the results change (a walk evaluates two or more outputs at every step).
        self._forces_cache = self.DeclareCacheEntry(
            "contact forces by part", ValueProducer(allocate=lambda: AbstractValue.Make(object()),
                                                    calc=self._calc_forces),
            {self._contact_port.ticket()})
        self.DeclareVectorOutputPort("foot_contact", 6, self._calc_contact)
        self.DeclareVectorOutputPort("foot_normal_force", 6, self._calc_force)
        self.DeclareVectorOutputPort("trunk_contact", 1, self._calc_trunk)
        self.DeclareVectorOutputPort("leg_link_force", 6, self._calc_leg_links)
        self.DeclareVectorOutputPort("self_contact", 1, self._calc_self)

    def _add(self, bodies, f: float, forces) -> None:
        foot, trunk, legs, own = forces
        if all(b in self._robot_bodies for b in bodies):
            own[0] = max(own[0], f)
            return
        for body in bodies:
            if body in self._foot_of_body:
                foot[self._foot_of_body[body]] += f
            elif body in self._leg_of_link:
                legs[self._leg_of_link[body]] += f
            elif body == self._trunk:
                trunk[0] += f

    def _forces(self, context):
        """(foot (6), trunk (1), leg links (6), self (1)) contact forces. [N]"""
        return self._forces_cache.Eval(context)

    def _calc_forces(self, context, value) -> None:
        results: ContactResults = self._contact_port.Eval(context)
        forces = (np.zeros(6), np.zeros(1), np.zeros(6), np.zeros(1))
        for k in range(results.num_point_pair_contacts()):
            info = results.point_pair_contact_info(k)
            self._add((int(info.bodyA_index()), int(info.bodyB_index())),
                      float(np.linalg.norm(info.contact_force())), forces)
        for k in range(results.num_hydroelastic_contacts()):
            info = results.hydroelastic_contact_info(k)
            surface = info.contact_surface()
            bodies = tuple(self._body_of_geometry.get(g, -1) for g in (surface.id_M(), surface.id_N()))
            self._add(bodies, float(np.linalg.norm(info.F_Ac_W().translational())), forces)
        value.set_value(forces)

    def _calc_contact(self, context, output: BasicVector):
        output.SetFromVector((self._forces(context)[0] > self._threshold).astype(float))

    def _calc_force(self, context, output: BasicVector):
        output.SetFromVector(self._forces(context)[0])

    def _calc_trunk(self, context, output: BasicVector):
        output.SetFromVector([float(self._forces(context)[1][0] > self._threshold)])

    def _calc_leg_links(self, context, output: BasicVector):
        output.SetFromVector(self._forces(context)[2])

    def _calc_self(self, context, output: BasicVector):
        output.SetFromVector(self._forces(context)[3])


class ImuAssembler(LeafSystem):
    """Packs the IMU vector: base orientation, gyroscope and accelerometer measurements.

    .. pydrake_system::

        name: ImuAssembler
        input_ports:
        - body_poses
        - angular_velocity
        - acceleration
        output_ports:
        - imu

    Output: quaternion w x y z of the base in world (4), angular velocity in the base frame
    (3) [rad/s], proper acceleration (specific force, as an accelerometer reads; +g up at rest)
    in the base frame (3) [m/s^2].
    """

    def __init__(self, *, plant: MultibodyPlant, base_body_index):
        super().__init__()
        self._base = int(base_body_index)
        self._poses = self.DeclareAbstractInputPort("body_poses",
                                                    plant.get_body_poses_output_port().Allocate())
        self._gyro = self.DeclareVectorInputPort("angular_velocity", 3)
        self._accel = self.DeclareVectorInputPort("acceleration", 3)
        self.DeclareVectorOutputPort("imu", IMU_SIZE, self._calc_imu)

    def _calc_imu(self, context, output: BasicVector):
        X_WB = self._poses.Eval(context)[self._base]
        out = np.zeros(IMU_SIZE)
        out[0:4] = X_WB.rotation().ToQuaternion().wxyz()
        out[4:7] = self._gyro.Eval(context)
        out[7:10] = self._accel.Eval(context)
        output.SetFromVector(out)
