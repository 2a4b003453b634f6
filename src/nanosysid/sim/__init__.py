"""Flight simulator of the Crazyflie 2.1 Brushless: the benchmark's default data source.

Example::

    from nanosysid import sim
    sim.EFFECTS                                   # {name: description}
    flight = sim.simulate_flight("melon", run=1, effects={"rotor_drag": 1.0}, seed=0)
    oracle = sim.oracle(effects={"rotor_drag": 1.0})   # a predictor with the true dynamics

    def push(t, x, omega, omega_dot):             # a wrench of your own, body frame, SI units
        force = torch.zeros_like(x[..., :3]); force[..., 0] = 0.01
        return force, torch.zeros_like(force)
    flight = sim.simulate_flight("melon", effects={}, extra_wrench=push)

``effects=None`` means the default world (:data:`DEFAULT_WORLD`); ``{}`` means none. A batch
of flights, each with its own world, is a list of :class:`FlightSpec`.
"""

from __future__ import annotations

from typing import Mapping, Sequence

import numpy as np

from nanosysid.dataio import Flight
from nanosysid.errors import ConfigError
from nanosysid.sim.oracle import Oracle
from nanosysid.sim.simulator import FlightSpec, SimConfig, simulate, trajectory_reference
from nanosysid.sim.world import DEFAULT_WORLD, EFFECTS, ExtraWrench, World
from nanosysid.vehicle import Vehicle

__all__ = ["EFFECTS", "DEFAULT_WORLD", "World", "SimConfig", "FlightSpec", "flight_specs", "simulate_flight",
           "simulate_flights", "oracle", "trajectory_reference"]

DATE = "20250601"


def _world(effects: Mapping[str, float] | None) -> World:
    return World(dict(DEFAULT_WORLD) if effects is None else dict(effects))


def flight_specs(runs: Mapping[str, int], effects: Mapping[str, float] | None = None, seed: int = 0, *,
                 extra_wrench: ExtraWrench | None = None) -> list[FlightSpec]:
    """Runs 1..n of each trajectory of ``runs`` in one world, as :class:`FlightSpec`."""
    for traj, n in runs.items():
        if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 0:
            raise ConfigError(f"runs: {traj!r} = {n!r}; the number of runs of a trajectory is a whole number >= 0")
    specs = [FlightSpec(traj, k, effects=effects, seed=seed, extra_wrench=extra_wrench)
             for traj, n in runs.items() for k in range(1, int(n) + 1)]
    if not specs:
        raise ConfigError(f"runs: {dict(runs)} asks for no flight")
    return specs


def simulate_flights(
    runs: Mapping[str, int] | Sequence[FlightSpec],
    effects: Mapping[str, float] | None = None,
    seed: int = 0,
    *,
    noise: bool = True,
    cfg: SimConfig | None = None,
    vehicle: Vehicle | None = None,
    date: str = DATE,
    extra_wrench: ExtraWrench | None = None,
    progress: bool = True,
) -> list[Flight]:
    """Simulate flights as one batch: a list of :class:`FlightSpec` (each flight its own world,
    seed and extra wrench), or ``runs[trajectory]`` runs of each trajectory in one world."""
    if isinstance(runs, Mapping):
        specs = flight_specs(runs, effects, seed, extra_wrench=extra_wrench)
    else:
        specs = list(runs)
        if effects is not None or seed != 0 or extra_wrench is not None:
            raise TypeError("simulate_flights: with a list of FlightSpec, each spec names its own effects, seed and "
                            "extra_wrench")
    return simulate(specs, vehicle=vehicle, cfg=cfg, noise=noise, date=date, progress=progress)


def simulate_flight(
    trajectory: str,
    run: int = 1,
    effects: Mapping[str, float] | None = None,
    seed: int = 0,
    *,
    extra_wrench: ExtraWrench | None = None,
    **options,
) -> Flight:
    """One flight; the same as that flight from :func:`simulate_flights` with the same seed.

    Raises:
        ConfigError: a flight that leaves the room or the floor (its effects or extra wrench beyond
            what the controller flies), as the simulate stage refuses it.
    """
    from nanosysid.sim.envelope import check_flown

    spec = FlightSpec(trajectory, run, effects=effects, seed=seed, extra_wrench=extra_wrench)
    flight = simulate([spec], progress=options.pop("progress", False), **options)[0]
    world = "the default world" if effects is None else f"the effects {dict(effects)}"
    check_flown([flight], world + (" and the extra_wrench" if extra_wrench is not None else ""))
    return flight


def oracle(effects: Mapping[str, float] | None = None, *, vehicle: Vehicle | None = None, substeps: int = 4,
           dt: float = 0.01, rotor_delay: float | None = None, seed: int = 0,
           extra_wrench: ExtraWrench | None = None, compile: bool = True, held: bool = False) -> Oracle:
    """A predictor for :func:`nanosysid.protocol.evaluate` with the true dynamics of the world.

    ``rotor_delay`` (s) is the delay of the rotor speeds in the data behind the true ones; by
    default the ``telemetry_delay`` effect's, as in the simulator's direct output. Flights from
    the data pipeline have the motor stream aligned already: 0. ``seed`` is the simulation's:
    with it the oracle replays each flight's turbulence. ``extra_wrench`` is the user-supplied
    wrench the flights were simulated with. ``compile``: its derivative runs compiled, as the
    simulator's step (``sim.flight.compile``); false runs it eagerly. ``held``: the angular
    velocity held (``dw/dt = 0``), the limit of a model that holds it as the paper's physics model
    does (run eagerly).
    """
    return Oracle(_world(effects), vehicle, dt=dt, substeps=substeps, rotor_delay=rotor_delay, seed=seed,
                  extra_wrench=extra_wrench, compile=compile, held=held)


def oracle_of(*, effects: Mapping[str, float] | None = None, vehicle: Vehicle | Mapping | None = None,
              substeps: int = 4, dt: float = 0.01, rotor_delay: float | None = None, seed: int = 0,
              compile: bool = True, held: bool = False) -> Oracle:
    """:func:`oracle` from a model's config block (``models.oracle`` less ``kind``, ``artifact``
    and ``code``): the vehicle a mapping (None: the paper's), the effects a mapping."""
    v = Vehicle() if vehicle is None else vehicle if isinstance(vehicle, Vehicle) else Vehicle.from_mapping(vehicle)
    return oracle(None if effects is None else dict(effects), vehicle=v, substeps=substeps, dt=dt,
                  rotor_delay=rotor_delay, seed=int(seed), compile=compile, held=held)
