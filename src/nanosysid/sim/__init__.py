"""Flight simulator of the Crazyflie 2.1 Brushless: the benchmark's default data source.

Example::

    from nanosysid import sim
    sim.EFFECTS                                   # {name: description}
    flight = sim.simulate_flight("melon", run=1, effects={"rotor_drag": 1.0}, seed=0)
    oracle = sim.oracle(effects={"rotor_drag": 1.0})   # a predictor with the true dynamics

``effects=None`` means the default world (every effect at strength 1.0); ``{}`` means none.
"""

from __future__ import annotations

from typing import Mapping

from nanosysid.dataio import Flight
from nanosysid.sim.oracle import Oracle
from nanosysid.sim.simulator import SimConfig, simulate
from nanosysid.sim.world import DEFAULT_WORLD, EFFECTS, World
from nanosysid.vehicle import Vehicle

__all__ = ["EFFECTS", "DEFAULT_WORLD", "World", "SimConfig", "flight_specs", "simulate_flight", "simulate_flights",
           "oracle"]

DATE = "20250601"


def _world(effects: Mapping[str, float] | None) -> World:
    return World(dict(DEFAULT_WORLD) if effects is None else dict(effects))


def flight_specs(runs: Mapping[str, int], date: str = DATE) -> list[tuple[str, str, int]]:
    """``(name, trajectory, run)`` for runs 1..n of each trajectory; names ``<trajectory>_<date>_run<k>``."""
    return [(f"{traj}_{date}_run{k}", traj, k) for traj, n in runs.items() for k in range(1, int(n) + 1)]


def simulate_flights(
    runs: Mapping[str, int],
    effects: Mapping[str, float] | None = None,
    seed: int = 0,
    *,
    noise: bool = True,
    cfg: SimConfig | None = None,
    vehicle: Vehicle | None = None,
    date: str = DATE,
    progress: bool = True,
) -> list[Flight]:
    """Simulate ``runs[trajectory]`` runs of each trajectory as one batch."""
    return simulate(flight_specs(runs, date), world=_world(effects), vehicle=vehicle, cfg=cfg, seed=seed, noise=noise,
                    progress=progress)


def simulate_flight(
    trajectory: str,
    run: int = 1,
    effects: Mapping[str, float] | None = None,
    seed: int = 0,
    **options,
) -> Flight:
    """One flight; the same as that flight from :func:`simulate_flights` with the same seed."""
    name = f"{trajectory}_{options.pop('date', DATE)}_run{run}"
    return simulate([(name, trajectory, run)], world=_world(effects), seed=seed,
                    progress=options.pop("progress", False), **options)[0]


def oracle(effects: Mapping[str, float] | None = None, *, vehicle: Vehicle | None = None, substeps: int = 4,
           dt: float = 0.01, rotor_delay: float | None = None) -> Oracle:
    """A predictor for :func:`nanosysid.benchmark.evaluate` with the true dynamics of the world.

    ``rotor_delay`` (s) is the delay of the rotor speeds in the data behind the true ones; by
    default the ``telemetry_delay`` effect's, as in the simulator's direct output. Flights from
    the data pipeline have the motor stream aligned already: 0.
    """
    return Oracle(_world(effects), vehicle, dt=dt, substeps=substeps, rotor_delay=rotor_delay)
