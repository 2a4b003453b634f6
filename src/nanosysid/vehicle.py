"""Physical parameters of the benchmark vehicle, the Crazyflie 2.1 Brushless."""

from __future__ import annotations

from dataclasses import asdict, dataclass, fields
from typing import Any, Mapping

__all__ = ["Vehicle"]


@dataclass(frozen=True)
class Vehicle:
    """Rigid-body and rotor parameters; defaults are the benchmark paper's values.

    Attributes:
        mass: Total mass (kg), battery and decks included.
        inertia: Diagonal of the body-frame inertia matrix (kg m^2), from Crazyflow.
        arm: Effective lever arm L (m): 50 mm centre-to-motor times cos(45 deg).
        k_f: Thrust coefficient (N s^2/rad^2), identified in the paper.
        k_m: Moment coefficient (N m s^2/rad^2): thrust-stand yaw torque per thrust (5.69 mm,
            crazyflie-firmware's THRUST2TORQUE) times k_F; the paper's closed-loop fit is 7.73e-11.
        gravity: Gravitational acceleration (m/s^2).
    """

    mass: float = 0.045
    inertia: tuple[float, float, float] = (2.3951e-5, 2.3951e-5, 3.2347e-5)
    arm: float = 0.03535
    k_f: float = 3.72e-8
    k_m: float = 2.1177e-10
    gravity: float = 9.81

    @classmethod
    def from_mapping(cls, cfg: Mapping[str, Any]) -> "Vehicle":
        """Build from a config mapping; unknown keys are an error, missing keys take defaults."""
        names = {f.name for f in fields(cls)}
        unknown = set(cfg) - names
        if unknown:
            raise KeyError(f"vehicle config: unknown keys {sorted(unknown)}; expected {sorted(names)}")
        kw = dict(cfg)
        if "inertia" in kw:
            kw["inertia"] = tuple(float(v) for v in kw["inertia"])
        return cls(**kw)

    def dynamics_kwargs(self) -> dict[str, Any]:
        """Keyword arguments of :func:`nanosysid.dynamics.quad_dynamics`."""
        return asdict(self)

    @property
    def hover_speed(self) -> float:
        """Rotor speed (rad/s) at which the four rotors together carry the weight."""
        return (self.mass * self.gravity / (4 * self.k_f)) ** 0.5
