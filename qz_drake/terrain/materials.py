"""Ground materials: contact stiffness, damping and friction of paper 000 (Sec. 3 and 4.3).

Paper 000 cites Bosworth et al.'s stiffness measurements: concrete stiffer than 300 kN/m, foam
about 20 kN/m, wood about their average. Its only damping figure is that of its simulated ground
(Sec. 4.3: 70 kN/m with 200 N*s/m); it gives none per material, so all three take 200 N*s/m.
Friction is not in the paper; we take typical rubber-foot values (concrete 0.8, wood 0.6,
foam 0.9) and give the static and the dynamic coefficient the same value, since Drake's
discrete contact solvers use the dynamic one only.

How the measured numbers become Drake's contact parameters, at the nominal foot load
F0 = 60 kg * g / 3 (tripod stance, ``NOMINAL_FOOT_LOAD``):

* Point contact: Drake's Hunt-Crossley force is f = k x (1 + d xdot), a damping k d x that
  grows with the penetration x. ``damping / stiffness`` has units of seconds, not s/m, so it
  cannot be d; instead we match the linear damping at the static penetration x0 = F0 / k:
  k d x0 = damping, i.e. d = damping / F0 [s/m] (about 1 s/m).
* Hydroelastic contact: a compliant sphere of radius R and modulus E pressed delta into a rigid
  plane carries F = pi E (delta^2 - 2 delta^3 / (3 R)) (Drake's sphere pressure field
  E * depth / R; force about pi E delta^2 for a small delta). We choose E so that a
  ``FOOT_RADIUS`` = 3 cm foot sinks the same x0 = F0 / k under F0 as under point contact:
  E = F0 / (pi (x0^2 - 2 x0^3 / (3 R))). Drake's tessellated sphere reaches that force only
  with a fine mesh: with resolution_hint = R / 10 it carries 0.99 F0 (foam), 0.92 F0 (wood),
  0.84 F0 (concrete) at x0; a hint equal to R gives an octahedron that is many times softer
  at these sub-centimetre depths.
"""

from __future__ import annotations

import dataclasses
import math

from qz_drake.errors import TerrainError, bad_value

# Standard gravity. [m/s^2]
_GRAVITY = 9.81
# Load on one foot of Qingzhui (60 kg) standing on a tripod. [N]
NOMINAL_FOOT_LOAD = 60.0 * _GRAVITY / 3.0
# Foot sphere radius the hydroelastic modulus is matched for. [m]
# Qingzhui's foot sphere (qz_drake.robot.params). [m]
FOOT_RADIUS = 0.03


@dataclasses.dataclass(frozen=True)
class GroundMaterial:
    """Contact properties of a ground material; build presets with :func:`make_ground_material`,
    which derives the Hunt-Crossley dissipation and the hydroelastic modulus."""

    name: str
    # Point-contact stiffness. [N/m]
    stiffness: float
    # Linear contact damping, as measured. [N*s/m]
    damping: float
    # Drake's Hunt-Crossley dissipation, damping / NOMINAL_FOOT_LOAD. [s/m]
    hunt_crossley_dissipation: float
    # Coulomb friction coefficients (static >= dynamic).
    static_friction: float
    dynamic_friction: float
    # Hydroelastic modulus giving a FOOT_RADIUS sphere the point contact's static sinkage. [Pa]
    hydroelastic_modulus: float

    def __post_init__(self):
        for field in ("stiffness", "hydroelastic_modulus"):
            value = getattr(self, field)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
                raise bad_value(f"material.{field}", value, f"must be finite and positive ({self.name})",
                                TerrainError)
        for field in ("damping", "hunt_crossley_dissipation", "static_friction", "dynamic_friction"):
            value = getattr(self, field)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value >= 0):
                raise bad_value(f"material.{field}", value, f"must be finite and non-negative ({self.name})",
                                TerrainError)
        if self.dynamic_friction > self.static_friction:
            raise bad_value("material.dynamic_friction", self.dynamic_friction,
                            f"must not exceed static_friction {self.static_friction} ({self.name})", TerrainError)


def hydroelastic_modulus_for(stiffness: float, load: float = NOMINAL_FOOT_LOAD,
                             foot_radius: float = FOOT_RADIUS) -> float:
    """The modulus [Pa] at which a compliant foot sphere sinks load / stiffness under ``load``."""
    x0 = load / stiffness
    return load / (math.pi * (x0 ** 2 - 2.0 * x0 ** 3 / (3.0 * foot_radius)))


def make_ground_material(name: str, *, stiffness: float, damping: float, static_friction: float,
                         dynamic_friction: float | None = None) -> GroundMaterial:
    """A material from measured stiffness [N/m], damping [N*s/m] and friction, with Drake's
    parameters derived as the module docstring explains."""
    if not (math.isfinite(stiffness) and stiffness > NOMINAL_FOOT_LOAD / FOOT_RADIUS):
        raise bad_value("material.stiffness", stiffness,
                        f"must exceed {NOMINAL_FOOT_LOAD / FOOT_RADIUS:.0f} N/m (the foot would sink its radius)",
                        TerrainError)
    return GroundMaterial(
        name=name, stiffness=stiffness, damping=damping,
        hunt_crossley_dissipation=damping / NOMINAL_FOOT_LOAD,
        static_friction=static_friction,
        dynamic_friction=static_friction if dynamic_friction is None else dynamic_friction,
        hydroelastic_modulus=hydroelastic_modulus_for(stiffness))


# Paper 000's damping of its simulated ground. [N*s/m]
_PAPER_DAMPING = 200.0

MATERIALS: dict[str, GroundMaterial] = {
    # Hard ground: "harder than 300 kN/m".
    "concrete": make_ground_material("concrete", stiffness=400e3, damping=_PAPER_DAMPING, static_friction=0.8),
    # Medium ground: about the average of concrete and foam.
    "wood": make_ground_material("wood", stiffness=210e3, damping=_PAPER_DAMPING, static_friction=0.6),
    # Soft ground: about 20 kN/m.
    "foam": make_ground_material("foam", stiffness=20e3, damping=_PAPER_DAMPING, static_friction=0.9),
}


def get_material(name: str) -> GroundMaterial:
    """The named preset; raises TerrainError naming ``material`` and listing the valid names."""
    if not isinstance(name, str) or name not in MATERIALS:
        raise bad_value("material", name, f"unknown ground material (valid: {', '.join(MATERIALS)})", TerrainError)
    return MATERIALS[name]
