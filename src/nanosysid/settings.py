"""The settings' one schema: ``conf/`` holds every default, :data:`SCHEMA` every kind and bound.

Each setting's default value is written once, with its meaning, in the Hydra config of ``conf/``;
its kind and bound are written once, in :data:`SCHEMA`, by dotted key of the composed config
(``*`` stands for any part of a key; the first pattern that matches a key is its entry). The
library's settings dataclasses (:class:`~nanosysid.vehicle.Vehicle`,
:class:`~nanosysid.sim.simulator.SimConfig` and its noise,
:class:`~nanosysid.bags.recorder.RecorderConfig`, :class:`~nanosysid.preprocess.sync.SyncConfig`,
:class:`~nanosysid.preprocess.filtering.FilterConfig`) take their defaults from ``conf/`` through
:func:`defaults`, so calling the library without a config gives what the pipeline's default
config gives. ``tests/test_config.py`` checks that every setting of the composed config has an
entry and every entry names a setting. Choices that depend on installed libraries or on other
settings (an optimiser class, an accelerator, table horizons within the evaluated ones) are
checked by :func:`nanosysid.config.check_values` beside.

Stages take every value from ``params.yaml`` (their DVC params); the defaults read here serve the
library's callers outside the pipeline, so the files of ``conf/`` are no code dependency of a
stage.
"""

from __future__ import annotations

import dataclasses
import fnmatch
import functools
import math
from pathlib import Path
from typing import Any, Callable, Iterator

from omegaconf import OmegaConf

__all__ = ["CONF", "SCHEMA", "ALIASES", "LENGTHS", "defaults", "configured", "kind_of", "fits", "describe",
           "check_value", "leaves", "SOURCES"]

# conf/ of the project this library belongs to (the source checkout that `make venv` installs)
CONF = Path(__file__).resolve().parents[2] / "conf"

POSITIVE = "a positive number"
COUNT = "a positive whole number"
NONNEG = "a number >= 0"
NONNEG_COUNT = "a whole number >= 0"
COUNT_OR_NULL = "a positive whole number, or null"
COUNT_OR_AUTO = "a positive whole number or auto"
NONNEG_OR_NULL = "a number >= 0, or null"
TWO_OR_MORE = "a whole number >= 2"
SHARE = "a number from 0 to 1"
NUMBER = "a finite number"
TEXT = "text"
TEXT_OR_NULL = "text, or null"
FLAG = "true or false"
WAYPOINTS = "a list of [x, y, z] waypoints (m), or null"
FREE = "anything its user accepts"  # checked where it is used (an optimiser's arguments, a network's)
# a tuple of words: the setting takes one of them

SCHEMA: list[tuple[str, str | tuple[str, ...]]] = [
    # seeds and the vehicle, wherever a model or an oracle carries them
    ("seed", NONNEG_COUNT), ("*.seed", NONNEG_COUNT), ("*_seed", NONNEG_COUNT),
    ("*vehicle.mass", POSITIVE), ("*vehicle.inertia", POSITIVE), ("*vehicle.arm", POSITIVE),
    ("*vehicle.k_f", POSITIVE), ("*vehicle.k_m", POSITIVE), ("*vehicle.gravity", POSITIVE),
    # the simulator and its recording rig
    ("sim.out_dir", TEXT), ("sim.date", TEXT), ("sim.runs.*", NONNEG_COUNT), ("sim.effects.*", NONNEG),
    ("sim.flight.*_rate", POSITIVE), ("sim.flight.motor_tau", POSITIVE), ("sim.flight.noise.*", NONNEG),
    ("sim.flight.omega_min", POSITIVE), ("sim.flight.omega_max", POSITIVE), ("sim.flight.preroll", NONNEG),
    ("sim.flight.postroll", NONNEG), ("sim.flight.initial_offset", NONNEG), ("sim.flight.feedforward", SHARE),
    ("sim.flight.compile", FLAG),
    ("sim.flight.gains.*", NUMBER),
    ("sim.flight.trajectories.*.center", NUMBER), ("sim.flight.trajectories.*.n_points", COUNT),
    ("sim.flight.trajectories.melon.omega_start", NONNEG_OR_NULL),
    ("sim.flight.trajectories.melon.start_height", NONNEG_OR_NULL),
    ("sim.flight.trajectories.melon.start_from_centre", FLAG), ("sim.flight.trajectories.random.points", WAYPOINTS),
    ("sim.flight.trajectories.*", POSITIVE),
    ("sim.recorder.*_rate", POSITIVE), ("sim.recorder.host_epoch", NUMBER), ("sim.recorder.mocap_clock", NUMBER),
    ("sim.recorder.stm_clock", NUMBER), ("sim.recorder.stm_drift_ppm", NUMBER), ("sim.recorder.wifi_loss", SHARE),
    ("sim.recorder.motor_missed", SHARE), ("sim.recorder.*", NONNEG),
    # the data chain: extract, sync, filter
    ("preprocess.*_dir", TEXT),
    ("preprocess.sync.rate", POSITIVE), ("preprocess.sync.max_lag", POSITIVE),
    ("preprocess.sync.xcorr_band", POSITIVE), ("preprocess.sync.xcorr_step", POSITIVE),
    ("preprocess.sync.min_samples", COUNT), ("preprocess.sync.warn_gap", NONNEG_COUNT),
    ("preprocess.sync.warn_loss", NONNEG), ("preprocess.sync.lag_threshold", POSITIVE),
    ("preprocess.sync.lag_window", POSITIVE), ("preprocess.sync.lag_tolerance", POSITIVE),
    ("preprocess.sync.lag_reach", POSITIVE), ("preprocess.sync.lag_block", POSITIVE),
    ("preprocess.sync.max_loss", NONNEG),
    ("preprocess.filter.rate", POSITIVE), ("preprocess.filter.order", COUNT),
    ("preprocess.filter.position", POSITIVE), ("preprocess.filter.velocity", POSITIVE),
    ("preprocess.filter.acceleration", POSITIVE), ("preprocess.filter.motors", POSITIVE),
    ("preprocess.filter.quaternion", POSITIVE), ("preprocess.filter.max_gap", NONNEG_COUNT),
    ("preprocess.filter.max_hold", NONNEG_COUNT),
    ("preprocess.topics.motors.erpm_unit", COUNT), ("preprocess.topics.motors.pole_pairs", COUNT),
    ("preprocess.topics.motors.invalid", NONNEG_COUNT),
    ("preprocess.topics.odom.velocity_frame", ("world", "body")), ("preprocess.topics.*", TEXT),
    ("data.source", TEXT), ("data.flights_dir", TEXT), ("data.rotor_delay", NONNEG_OR_NULL),
    ("data.truth", ("sim",)),
    ("paths.export", TEXT_OR_NULL), ("paths.*", TEXT), ("split.*", TEXT),
    ("preprocess.format", ("bags", "logs")), ("preprocess.sync.position", ("mocap", "onboard")),
    ("rig.local", TEXT_OR_NULL), ("rig.manifest", TEXT), ("rig.upstream.*", TEXT),
    ("rig.paths.*", TEXT), ("rig.logs.accel_frame", ("world", "body")), ("rig.logs.max_erpm", POSITIVE),
    ("rig.logs.pole_pairs", POSITIVE), ("rig.logs.erpm_unit", POSITIVE), ("rig.logs.keep_incomplete", FLAG),
    ("rig.logs.aliases.*", TEXT), ("rig.logs.flights.*", TEXT),
    # models
    ("models.*.kind", TEXT), ("models.*.artifact", TEXT), ("models.*.code", TEXT), ("models.*.checkpoint", TEXT), ("models.*.model", TEXT),
    # (``*`` spans dots: models.*.dt is also phys_res's models.phys_res.physics.dt)
    ("models.*.identified", TEXT_OR_NULL), ("models.*.dt", POSITIVE), ("models.*.substeps", COUNT),
    ("models.oracle.effects.*", NONNEG), ("models.*.rotor_delay", NONNEG_OR_NULL), ("models.oracle.compile", FLAG),
    ("models.*.network.*", FREE),
    ("models.*.train.horizon", COUNT), ("models.*.train.horizon_decay", NONNEG), ("models.*.train.stride", COUNT), ("models.*.train.batch_size", COUNT),
    ("models.*.train.epochs", COUNT), ("models.*.train.patience", NONNEG_COUNT), ("models.*.train.compile", FLAG),
    ("models.*.train.threads", COUNT),
    ("models.*.train.optimizer.lr", POSITIVE), ("models.*.train.val_runs", COUNT),
    ("models.*.train.optimizer.*", FREE), ("models.*.train.scheduler", FREE), ("models.*.train.scheduler.*", FREE),
    ("learned.*", TEXT), ("trainer.devices", COUNT_OR_AUTO),
    ("trainer.every_model", FREE),  # null; its keys are a train block's (:data:`ALIASES`)
    ("trainer.accelerator", ("auto", "cpu", "gpu", "cuda", "mps")),  # Lightning's
    # evaluation, identification, reports
    ("eval.horizon", COUNT), ("eval.batch_size", COUNT), ("eval.table_horizons", COUNT),
    ("identify.out_dir", TEXT), ("identify.calibration", TEXT),
    ("identify.savgol_window", COUNT), ("identify.savgol_order", NONNEG_COUNT),
    ("identify.iv_blocks", COUNT), ("identify.iv_lags", NONNEG), ("identify.inertia_z_range", POSITIVE),
    ("report.lineplot.flight", TEXT_OR_NULL), ("report.lineplot.window", NONNEG), ("report.lineplot.smooth", COUNT),
    ("report.lineplot.models", TEXT), ("report.note", TEXT_OR_NULL), ("report.*", TEXT),
    ("visualize.out_dir", TEXT), ("visualize.stride", COUNT),
    ("export.models.*", TEXT), ("export.out_dir", TEXT),
    ("export.onnx_samples", COUNT), ("export.onnx_tolerance", POSITIVE), ("export.mcu.flight", TEXT_OR_NULL),
    ("export.mcu.enabled", FLAG),
    ("export.mcu.start", NONNEG_COUNT), ("export.mcu.steps", COUNT), ("export.mcu.tolerance", POSITIVE),
    # discovery (its oracle is a model's block)
    ("discover.folds", TWO_OR_MORE), ("discover.block", POSITIVE), ("discover.alpha", SHARE), ("discover.share", SHARE),
    ("discover.sindy", FLAG), ("discover.flights_out", FLAG), ("discover.out_dir", TEXT), ("discover.report_dir", TEXT),
    ("discover.identified", TEXT_OR_NULL), ("discover.velocity", ("estimate", "position")),
    ("discover.savgol_window", COUNT), ("discover.savgol_order", NONNEG_COUNT),
    ("discover.delay_step", POSITIVE), ("discover.delay_max", NONNEG),
    ("discover.chain.accel", NONNEG_OR_NULL), ("discover.chain.gyro", NONNEG_OR_NULL),
    ("discover.chain.rotor", NONNEG_OR_NULL), ("discover.chain.order", COUNT), ("discover.noise_draws", NONNEG_COUNT),
    ("discover.oracle.dt", POSITIVE), ("discover.oracle.substeps", COUNT), ("discover.oracle.effects.*", NONNEG),
    ("discover.oracle.rotor_delay", NONNEG_OR_NULL), ("discover.oracle.compile", FLAG), ("discover.oracle.*", TEXT),
    ("discover.oracle", FREE),  # a model's block, or null where no oracle applies (real data)
    ("drone_models.name", TEXT), ("drone_models.source", TEXT),
    # the initialization-window track
    ("window.init", COUNT), ("window.models", TEXT), ("window.base", TEXT), ("window.ridge", POSITIVE),
    ("window.identified", TEXT), ("window.out_dir", TEXT),
    # the low-frequency torque's hypotheses
    ("hypotheses.cutoff", POSITIVE), ("hypotheses.holds", FLAG), ("hypotheses.identified", TEXT),
    ("hypotheses.worlds.*", NONNEG_COUNT), ("hypotheses.duration", POSITIVE),
    ("hypotheses.source", TEXT), ("hypotheses.out_dir", TEXT), ("hypotheses.worlds_dir", TEXT),
    # the campaign and the launcher
    ("campaign.worlds", COUNT), ("campaign.chunk", COUNT), ("campaign.duration", POSITIVE),
    ("campaign.user_share", SHARE), ("campaign.max_effects", NONNEG_COUNT), ("campaign.relevant", NONNEG),
    ("campaign.out_dir", TEXT), ("campaign.families.*", NONNEG_COUNT),
    ("launcher.workers", COUNT_OR_NULL), ("launcher.threads", COUNT), ("launcher.time_min", COUNT),
    ("launcher.mem_gb", POSITIVE), ("launcher.cpus_per_task", COUNT), ("launcher.partition", TEXT_OR_NULL),
    ("launcher.kind", ("local", "slurm")), ("launcher.cluster", ("slurm", "local", "debug")), ("launcher.*", TEXT),
]

# settings that are vectors: how many values each takes (1: a plain number too), and what they are
LENGTHS: list[tuple[str, tuple[int, ...], str]] = [
    ("*vehicle.inertia", (3,), "three numbers (body axes x, y, z)"),
    ("sim.flight.noise.gyro", (1, 3), "one number, or three (roll, pitch, yaw)"),
    ("sim.flight.noise.accel_bias", (1, 3), "one number, or three (body axes x, y, z)"),
    ("sim.flight.trajectories.*.center", (3,), "three numbers (x, y, z)"),
    ("sim.flight.trajectories.*.box", (3,), "three numbers (widths along x, y, z)"),
]


# settings whose keys are another block's: the kind of ``trainer.every_model.epochs`` is that of
# any learned model's ``models.<name>.train.epochs``
ALIASES = {"trainer.every_model.": "models.*.train."}


def kind_of(key: str) -> str | tuple[str, ...] | None:
    """The schema's kind of the setting ``key`` (dotted), or None where no entry matches."""
    for alias, block in ALIASES.items():
        if key.startswith(alias):
            key = block.replace("*", "_") + key[len(alias):]
    return next((kind for pattern, kind in SCHEMA if fnmatch.fnmatchcase(key, pattern)), None)


def describe(kind: str | tuple[str, ...]) -> str:
    """What a setting of ``kind`` must be, in words."""
    return kind if isinstance(kind, str) else f"one of {', '.join(kind)}"


def fits(value: object, kind: str | tuple[str, ...]) -> bool:
    """Whether one value (a list's element) is of ``kind``."""
    if isinstance(kind, tuple):
        return isinstance(value, str) and value in kind
    if kind == FREE:
        return True
    if kind in (TEXT, TEXT_OR_NULL):
        return isinstance(value, str) or (value is None and kind == TEXT_OR_NULL)
    if kind == FLAG:
        return isinstance(value, bool)
    if kind == COUNT_OR_AUTO:
        return value == "auto" or fits(value, COUNT)
    if kind == WAYPOINTS:
        return value is None or (isinstance(value, (list, tuple)) and len(value) == 3
                                 and all(fits(c, NUMBER) for c in value))
    if value is None:
        return kind in (COUNT_OR_NULL, NONNEG_OR_NULL)
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        return False
    if kind in (COUNT, NONNEG_COUNT, TWO_OR_MORE, COUNT_OR_NULL) and not isinstance(value, int):
        return False
    if kind == TWO_OR_MORE:
        return value >= 2
    if kind == SHARE:
        return 0 <= value <= 1
    if kind == NUMBER:
        return True
    return value > 0 if kind in (POSITIVE, COUNT, COUNT_OR_NULL) else value >= 0


def check_value(key: str, value: object, *, where: str) -> None:
    """Refuse a value of the setting ``key`` that is not of its schema kind (a list's every element
    checked) or, for a vector, not of its length (:data:`LENGTHS`). A key the schema does not know
    is checked by its user (a new network's arguments).

    Raises:
        ConfigError: naming ``where``, the setting, the value and what it must be.
    """
    from nanosysid.errors import ConfigError

    for pattern, lengths, what in LENGTHS:
        if fnmatch.fnmatchcase(key, pattern):
            if (len(value) if isinstance(value, (list, tuple)) else 1) not in lengths:
                raise ConfigError(f"{where}: {key} must be {what}, got {value!r}")
            break
    kind = kind_of(key)
    if kind is None:
        return
    for v in value if isinstance(value, (list, tuple)) else (value,):
        if not fits(v, kind):
            raise ConfigError(f"{where}: {key} must be {describe(kind)}, got {value!r}")


def leaves(node: object, key: str = "") -> Iterator[tuple[str, object]]:
    """Every ``(dotted key, value)`` of a nested mapping; a list is one value."""
    if isinstance(node, dict):
        for k, v in node.items():
            yield from leaves(v, f"{key}.{k}" if key else str(k))
    else:
        yield key, node


# the files of conf/ the library's dataclasses read their defaults from
SOURCES = ("vehicle/cf21bl.yaml", "sim/default.yaml", "preprocess/default.yaml")


@functools.cache
def _read(file: str) -> dict[str, Any]:
    path = CONF / file
    if not path.exists():
        raise FileNotFoundError(f"{path}: the defaults of the library's settings are read from the project's conf/; "
                                "install the library from its source checkout (`make venv`)")
    return OmegaConf.to_container(OmegaConf.load(path), resolve=False)


def defaults(file: str, *keys: str) -> dict[str, Any]:
    """The block ``keys`` of ``conf/<file>`` as plain data (a fresh copy): the default values of
    a settings dataclass."""
    if file not in SOURCES:
        raise ValueError(f"{file}: not one of the files the library reads its defaults from ({', '.join(SOURCES)})")
    node: Any = _read(file)
    for k in keys:
        node = node[k]
    return OmegaConf.to_container(OmegaConf.create(node)) if isinstance(node, (dict, list)) else node


def configured(file: str, *keys: str, own: tuple[str, ...] = ()) -> Callable[[type], type]:
    """A frozen dataclass whose fields' defaults are the block ``keys`` of ``conf/<file>`` (lists
    become tuples). Every field but those in ``own`` (which set their defaults themselves) must
    have its value there, and every value of the block a field."""
    def wrap(cls: type) -> type:
        values = defaults(file, *keys)
        names = [n for n in cls.__dict__.get("__annotations__", {}) if n not in own]
        where = f"{CONF / file}: {'.'.join(keys) or 'the file'}"
        missing, extra = set(names) - set(values), set(values) - set(names) - set(own)
        if missing or extra:
            raise TypeError(f"{where} and {cls.__name__} disagree: no value for {sorted(missing)}, no field for "
                            f"{sorted(extra)}")
        for name in names:
            v = values[name]
            setattr(cls, name, tuple(v) if isinstance(v, list) else v)
        prefix = ".".join([Path(file).parent.name, *keys])
        own_check = cls.__dict__.get("__post_init__")

        def __post_init__(self) -> None:
            # the schema's bounds hold wherever the dataclass is made, from a config or from
            # Python (a vehicle of mass -1 kg is refused, not scored)
            for name in names:
                check_value(f"{prefix}.{name}", getattr(self, name), where=cls.__name__)
            if own_check is not None:
                own_check(self)

        cls.__post_init__ = __post_init__
        return dataclasses.dataclass(frozen=True)(cls)

    return wrap
