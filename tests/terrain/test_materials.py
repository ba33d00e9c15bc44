"""Ground materials: the paper's numbers and the Drake parameters derived from them."""

import dataclasses
import math

import numpy as np
import pytest

from qz_drake.errors import TerrainError
from qz_drake.terrain import (FOOT_RADIUS, MATERIALS, NOMINAL_FOOT_LOAD, GroundMaterial, get_material,
                              make_ground_material)


def test_presets_follow_the_paper():
    concrete, wood, foam = (get_material(n) for n in ("concrete", "wood", "foam"))
    assert set(MATERIALS) == {"concrete", "wood", "foam"}
    assert concrete.stiffness > 300e3
    assert foam.stiffness == pytest.approx(20e3)
    assert wood.stiffness == pytest.approx((concrete.stiffness + foam.stiffness) / 2)
    assert (concrete.static_friction, wood.static_friction, foam.static_friction) == (0.8, 0.6, 0.9)
    for m in MATERIALS.values():
        assert m.damping == 200.0 and m.dynamic_friction <= m.static_friction


def test_hunt_crossley_dissipation_matches_the_damping_at_the_nominal_load():
    assert NOMINAL_FOOT_LOAD == pytest.approx(196.2)
    for m in MATERIALS.values():
        x0 = NOMINAL_FOOT_LOAD / m.stiffness
        # Linearised Hunt-Crossley damping k d x0 equals the measured damping.
        assert m.stiffness * m.hunt_crossley_dissipation * x0 == pytest.approx(m.damping)
    assert get_material("foam").hunt_crossley_dissipation == pytest.approx(200.0 / 196.2)


def test_hydroelastic_modulus_by_hand():
    # Foam: x0 = 196.2 / 20e3 = 9.81 mm; E = F0 / (pi (x0^2 - 2 x0^3 / (3 * 0.03))).
    x0 = 0.00981
    expected = 196.2 / (math.pi * (x0 ** 2 - 2 * x0 ** 3 / 0.09))
    assert get_material("foam").hydroelastic_modulus == pytest.approx(expected)
    assert expected == pytest.approx(8.30e5, rel=1e-3)
    assert get_material("concrete").hydroelastic_modulus == pytest.approx(2.624e8, rel=1e-3)  # x0 = 0.49 mm


@pytest.mark.parametrize("name", ["foam", "concrete"])
def test_drake_hydroelastic_foot_sinks_like_the_point_contact(name):
    """A finely meshed compliant foot pressed x0 = F0 / k into rigid ground carries about F0."""
    from pydrake.geometry import (AddCompliantHydroelasticProperties, AddRigidHydroelasticProperties, Box,
                                  HydroelasticContactRepresentation, ProximityProperties, Sphere)
    from pydrake.math import RigidTransform
    from pydrake.multibody.plant import AddMultibodyPlantSceneGraph
    from pydrake.multibody.tree import SpatialInertia
    from pydrake.systems.framework import DiagramBuilder

    material = get_material(name)
    x0 = NOMINAL_FOOT_LOAD / material.stiffness
    builder = DiagramBuilder()
    plant, scene_graph = AddMultibodyPlantSceneGraph(builder, 0.0)
    foot = plant.AddRigidBody("foot", SpatialInertia.SolidSphereWithMass(1.0, FOOT_RADIUS))
    compliant = ProximityProperties()
    AddCompliantHydroelasticProperties(FOOT_RADIUS / 10, material.hydroelastic_modulus, compliant)
    plant.RegisterCollisionGeometry(foot, RigidTransform(), Sphere(FOOT_RADIUS), "foot", compliant)
    rigid = ProximityProperties()
    AddRigidHydroelasticProperties(properties=rigid)
    plant.RegisterCollisionGeometry(plant.world_body(), RigidTransform([0, 0, -0.5]), Box(1, 1, 1), "ground", rigid)
    plant.Finalize()
    diagram = builder.Build()
    context = diagram.CreateDefaultContext()
    plant.SetFreeBodyPose(plant.GetMyContextFromRoot(context), foot, RigidTransform([0, 0, FOOT_RADIUS - x0]))
    query = scene_graph.get_query_output_port().Eval(scene_graph.GetMyContextFromRoot(context))
    force = 0.0
    for surface in query.ComputeContactSurfaces(HydroelasticContactRepresentation.kPolygon):
        mesh, pressure = surface.poly_mesh_W(), surface.poly_e_MN()
        force += sum(mesh.area(i) * pressure.EvaluateCartesian(i, mesh.element_centroid(i))
                     for i in range(mesh.num_elements()))
    # The tessellated sphere is a little softer than the smooth one the modulus is derived for.
    assert 0.75 * NOMINAL_FOOT_LOAD < force <= 1.02 * NOMINAL_FOOT_LOAD


def test_unknown_material_names_the_field_and_lists_valid_names():
    message = r"material = 'ice': unknown ground material \(valid: concrete, wood, foam\)"
    with pytest.raises(TerrainError, match=message):
        get_material("ice")


def test_bad_material_values_name_the_field():
    with pytest.raises(TerrainError, match=r"material\.stiffness = -1"):
        make_ground_material("mud", stiffness=-1.0, damping=100.0, static_friction=0.5)
    with pytest.raises(TerrainError, match=r"material\.dynamic_friction = 0\.9"):
        make_ground_material("mud", stiffness=50e3, damping=100.0, static_friction=0.5, dynamic_friction=0.9)
    with pytest.raises(TerrainError, match=r"material\.damping = nan"):
        make_ground_material("mud", stiffness=50e3, damping=float("nan"), static_friction=0.5)
    with pytest.raises(dataclasses.FrozenInstanceError):
        get_material("wood").stiffness = 1.0
    assert isinstance(get_material("wood"), GroundMaterial)
    assert np.isfinite([get_material("wood").hydroelastic_modulus]).all()
