"""Ground materials with the contact stiffness and damping of paper 002 (section 3).

Bosworth et al., cited there, measured concrete stiffer than 300 kN/m, foam about 20 kN/m and
wood about their average. Damping is chosen so each ground is well damped under a 60 kg robot;
Drake's point contact takes Hunt-Crossley dissipation d [s/m] with force ~ k x (1 + d xdot), so
we set d = damping / stiffness. The hydroelastic modulus gives a 3 cm foot sphere about the
same stiffness at 1 cm penetration (k ~ E * pi * a^2 / x with contact radius a^2 ~ 2 r x).
"""

from __future__ import annotations

import dataclasses
import math

from qz_drake.errors import TerrainError, bad_value

# Foot sphere radius used to convert stiffness into a hydroelastic modulus. [m]
_FOOT_RADIUS = 0.03


@dataclasses.dataclass(frozen=True)
class GroundMaterial:
    """Contact properties of a ground material."""

    name: str
    # Point-contact stiffness. [N/m]
    stiffness: float
    # Contact damping. [N*s/m]
    damping: float
    # Coulomb friction coefficients.
    static_friction: float
    dynamic_friction: float

    @property
    def hunt_crossley_dissipation(self) -> float:
        """Drake's Hunt-Crossley dissipation [s/m] = damping / stiffness."""
        return self.damping / self.stiffness

    @property
    def hydroelastic_modulus(self) -> float:
        """Modulus [Pa] giving a 3 cm foot sphere about this stiffness (k = 2 pi r E)."""
        return self.stiffness / (2.0 * math.pi * _FOOT_RADIUS)


MATERIALS: dict[str, GroundMaterial] = {
    # Hard ground: above 300 kN/m.
    "concrete": GroundMaterial("concrete", stiffness=400e3, damping=4000.0,
                               static_friction=0.8, dynamic_friction=0.75),
    # Between the two.
    "wood": GroundMaterial("wood", stiffness=150e3, damping=2500.0,
                           static_friction=0.6, dynamic_friction=0.55),
    # Soft ground: about 20 kN/m.
    "foam": GroundMaterial("foam", stiffness=20e3, damping=1000.0,
                           static_friction=0.9, dynamic_friction=0.85),
}


def get_material(name: str) -> GroundMaterial:
    """The named material; raises TerrainError naming ``material`` if unknown."""
    if name not in MATERIALS:
        raise bad_value("material", name, f"unknown ground material (valid: {', '.join(MATERIALS)})",
                        TerrainError)
    return MATERIALS[name]
