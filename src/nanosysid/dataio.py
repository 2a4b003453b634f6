"""Flights in the published CSV schema: reading with validation, and atomic writing.

The schema is the benchmark dataset's: one CSV per flight, named
``<trajectory>_<date>_run<k>.csv`` (or any name, in a ``train/`` and ``test/`` layout or listed in
a ``manifest.csv``: :func:`flight_catalog`), with columns ``t`` (s), the rotor speeds
``m1_rads..m4_rads`` (rad/s), the outputs ``x y z`` (m), ``vx vy vz`` (m/s, world),
``qx qy qz qw`` (body to world), ``wx wy wz`` (rad/s, body) and the accelerometer
``ax_body ay_body az_body`` (m/s^2, specific force in the body frame). Further columns
are kept as extras.
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
import re
import shutil
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterable, Iterator, Mapping, Sequence

import numpy as np
import pandas as pd

from nanosysid import guard
from nanosysid.errors import ConfigError, DataError

log = logging.getLogger("nanosysid.dataio")

__all__ = [
    "INPUT_COLUMNS",
    "OUTPUT_COLUMNS",
    "ACCEL_COLUMNS",
    "SCHEMA",
    "Flight",
    "parse_flight_name",
    "read_flight_csv",
    "write_flight_csv",
    "check_finite",
    "write_json",
    "read_json_record",
    "json_text",
    "session_of",
    "flight_catalog",
    "check_step",
    "FlightFile",
    "MANIFEST",
    "check_distinct",
    "flight_list",
    "atomic_file",
    "atomic_dir",
]

INPUT_COLUMNS = ["m1_rads", "m2_rads", "m3_rads", "m4_rads"]
OUTPUT_COLUMNS = ["x", "y", "z", "vx", "vy", "vz", "qx", "qy", "qz", "qw", "wx", "wy", "wz"]
ACCEL_COLUMNS = ["ax_body", "ay_body", "az_body"]
SCHEMA = ["t", *INPUT_COLUMNS, *OUTPUT_COLUMNS, *ACCEL_COLUMNS]
QUAT_COLUMNS = ["qx", "qy", "qz", "qw"]
QUAT_NORM_TOL = 1e-3
SAMPLE_PERIOD = 0.01  # s: the benchmark's 100 Hz, which every model and the protocol assume
PERIOD_TOL = 0.1  # share of the period a time step may be off it (jitter)


def check_step(dt: object, where: str) -> None:
    """Refuse a model's step ``dt`` (s) other than the flights' :data:`SAMPLE_PERIOD`: a model steps
    once per sample. ``where`` names the setting (``params.yaml: models.physics.dt``).

    Raises:
        ConfigError: naming ``where`` and the value.
    """
    if isinstance(dt, bool) or not isinstance(dt, (int, float)) or not abs(dt - SAMPLE_PERIOD) <= 1e-9:
        raise ConfigError(f"{where} = {dt!r} s; the flights are sampled every {SAMPLE_PERIOD:g} s, and a model steps "
                          "once per sample (use substeps for a finer integration)")

_NAME = re.compile(r"^(?P<trajectory>[A-Za-z][A-Za-z0-9-]*)_(?P<date>[^_]+)_run(?P<run>\d+)$")
_TRAJECTORY = re.compile(r"^[A-Za-z][A-Za-z0-9-]*$")
_SESSION = re.compile(r"^[^_/\\]+$")
MANIFEST = "manifest.csv"  # in a flights folder: which trajectory, run (and part) each file is
PARTS = ("train", "test")


@dataclass
class Flight:
    """One flight: time, inputs, outputs and extra columns, all sampled on the same grid.

    Attributes:
        name: File stem, ``<trajectory>_<date>_run<k>``.
        t: Time stamps ``(T,)`` in s.
        u: Rotor speeds ``(T, 4)`` in rad/s.
        y: Outputs ``(T, 13)``: position, velocity, quaternion xyzw, body rates.
        extra: Other columns by name, each ``(T,)`` (accelerometer, truth signals, ...).
        source: The file it was read from (None when made in memory): no output may replace it.
    """

    name: str
    t: np.ndarray
    u: np.ndarray
    y: np.ndarray
    extra: dict[str, np.ndarray] = field(default_factory=dict)
    source: Path | None = field(default=None, compare=False, repr=False)

    def __post_init__(self) -> None:
        for key in ("t", "u", "y"):  # a list or a table of numbers is taken as an array; anything else named
            value = getattr(self, key)
            if not (isinstance(value, np.ndarray) and np.issubdtype(value.dtype, np.number)):
                try:
                    setattr(self, key, np.asarray(value, dtype=np.float64))
                except (TypeError, ValueError) as e:
                    raise DataError(f"flight {self.name}: {key} must be an array of numbers ({e})") from None
        T = len(self.t)
        if self.u.shape != (T, 4) or self.y.shape != (T, 13):
            raise DataError(
                f"flight {self.name}: shapes t {self.t.shape}, u {self.u.shape}, y {self.y.shape};"
                f" expected ({T},), ({T}, 4), ({T}, 13)"
            )

    @property
    def trajectory(self) -> str:
        """Trajectory name (``square``, ``random``, ``chirp``, ``melon``), lower case."""
        return parse_flight_name(self.name)[0]

    @property
    def run(self) -> int:
        """Run number k of ``..._run<k>``."""
        return parse_flight_name(self.name)[1]

    def __len__(self) -> int:
        return len(self.t)

    def to_frame(self) -> pd.DataFrame:
        """The flight as a table in the published column order, extras last."""
        cols: dict[str, np.ndarray] = {"t": self.t}
        cols.update(zip(INPUT_COLUMNS, self.u.T))
        cols.update(zip(OUTPUT_COLUMNS, self.y.T))
        for k in ACCEL_COLUMNS:
            if k in self.extra:
                cols[k] = self.extra[k]
        cols.update({k: v for k, v in self.extra.items() if k not in cols})
        return pd.DataFrame(cols)


def flight_list(flights: Any, where: str, argument: str = "flights") -> list[Flight]:
    """``flights`` as a list of :class:`Flight`: a list, a tuple or a generator (read once).

    Raises:
        DataError: one Flight, a mapping (whose keys would be taken for flights), or an item that
            is no Flight; naming ``where`` and ``argument``.
    """
    if isinstance(flights, Flight):
        raise DataError(f"{where}: {argument} must be a list of flights, got one Flight ({flights.name}); pass "
                        "[flight]")
    if isinstance(flights, Mapping):
        raise DataError(f"{where}: {argument} must be a list of flights, got a {type(flights).__name__} (its keys "
                        "would be taken for flights); pass list(....values())")
    if isinstance(flights, (str, bytes)) or not isinstance(flights, Iterable):
        raise DataError(f"{where}: {argument} must be a list of flights, got {type(flights).__name__}")
    out = list(flights)
    for i, f in enumerate(out):
        if not isinstance(f, Flight):
            raise DataError(f"{where}: {argument}[{i}] is a {type(f).__name__}, not a Flight")
    return out


def parse_flight_name(name: str) -> tuple[str, int]:
    """``(trajectory, run)`` from ``<trajectory>_<date>_run<k>``; ValueError otherwise."""
    m = _NAME.match(Path(name).stem if name.endswith(".csv") else name)
    if m is None:
        raise ValueError(f"flight name {name!r} is not of the form <trajectory>_<date>_run<k>")
    return m["trajectory"].lower(), int(m["run"])


def json_text(payload, *, indent: int | None = 1, sort_keys: bool = False) -> str:
    """``payload`` as strict JSON text (RFC 8259: no NaN or Infinity), ending in a newline.

    A value that is not finite (a diverged rollout's error, say) is written as null, and a
    mapping at the top gains ``"non_finite"``: the paths of those values, so a reader learns
    why they are null rather than meeting a bare ``Infinity`` no JSON parser accepts.
    """
    replaced: list[str] = []

    def clean(v, path: str):
        if isinstance(v, dict):
            return {k: clean(x, f"{path}.{k}" if path else str(k)) for k, x in v.items()}
        if isinstance(v, (list, tuple)):
            return [clean(x, f"{path}[{i}]") for i, x in enumerate(v)]
        if isinstance(v, np.ndarray):
            return clean(v.tolist(), path)
        if isinstance(v, np.generic):
            v = v.item()
        if isinstance(v, float) and not np.isfinite(v):
            replaced.append(f"{path}: {v!r}")
            return None
        return v

    out = clean(payload, "")
    if replaced and isinstance(out, dict):
        out["non_finite"] = replaced
    return json.dumps(out, indent=indent, sort_keys=sort_keys, allow_nan=False) + "\n"


@dataclass(frozen=True)
class FlightFile:
    """One flight file of a folder a user brings, with the name the pipeline gives it.

    Attributes:
        path: The file.
        name: ``<trajectory>_<session>_run<k>``: the file's stem when it has that form, else
            from the manifest or the file's place in a ``train/``/``test/`` layout.
        part: ``"train"`` or ``"test"`` where the layout or the manifest says, else None.
    """

    path: Path
    name: str
    part: str | None = None


def flight_catalog(folder: str | os.PathLike, *, any_name: bool = False) -> list[FlightFile]:
    """The flights of a folder a user brings, each with its trajectory, run and part.

    A file's trajectory and run come, first found:

    1. from ``manifest.csv`` in ``folder``: columns ``file`` (relative to ``folder``),
       ``trajectory``, ``run``, optional ``session`` and ``part`` (``train``/``test``); every
       flight file under ``folder`` must have its row;
    2. from a name ``<trajectory>_<date>_run<k>.csv``;
    3. in a ``train/`` and ``test/`` layout, from any other name: the stem in lower case with
       every run of other characters made ``-`` is the trajectory, a number at its end the run
       (``Hover 03.csv``: trajectory ``hover``, run 3; ``loop.csv``: ``loop``, run 1).

    The part is the manifest's, else the layout folder's (``train/...`` or ``test/...``).
    ``any_name``: ``folder`` is itself one part (a benchmark's ``train/``), so 3. holds for it.

    Raises:
        DataError: a bad manifest (naming the file, the row and the field), a name of none of
            these forms, or two files of one flight.
    """
    folder = Path(folder)
    files = _csv_files(folder)
    manifest = _read_manifest(folder) if (folder / MANIFEST).is_file() else None
    layout = all((folder / p).is_dir() for p in PARTS)
    out, seen = [], {}
    for f in files:
        rel = f.relative_to(folder)
        top = rel.parts[0] if len(rel.parts) > 1 and rel.parts[0] in PARTS else None
        if manifest is not None:
            if rel.as_posix() not in manifest:
                raise DataError(f"{f}: not listed in {folder / MANIFEST} (add a row for it: file, trajectory, run; "
                                "or move it out of the folder)")
            trajectory, session, run, part = manifest.pop(rel.as_posix())
            part = part or (top if layout else None)
        elif _NAME.match(f.stem):
            trajectory, run = parse_flight_name(f.stem)
            session, part = session_of(f.stem), top if layout else None
        elif any_name or (layout and top is not None):
            trajectory, run = _name_of_stem(f)
            session, part = "own", top if layout else None
        else:
            raise DataError(f"{f}: flight name {f.stem!r} is not of the form <trajectory>_<date>_run<k>; rename it, "
                            f"put the flights in train/ and test/ folders, or list them in {folder / MANIFEST} "
                            "(columns file, trajectory, run)")
        _check_once(seen, (trajectory, session, run), f)
        out.append(FlightFile(f, f"{trajectory}_{session}_run{run}", part))
    if manifest:
        first = next(iter(manifest))
        raise DataError(f"{folder / MANIFEST}: row for file {first!r}: no such flight file under {folder}")
    return out


def _csv_files(folder: Path) -> list[Path]:
    """The ``.csv`` files under ``folder`` (not a manifest), sorted; a ``.CSV`` refused by name."""
    files = []
    for f in sorted(p for p in folder.rglob("*") if p.suffix.lower() == ".csv"):
        if f.suffix != ".csv":
            raise DataError(f"{f}: the extension is {f.suffix!r}; flight files end in '.csv' (rename it)")
        if f.name != MANIFEST:
            files.append(f)
    return files


def _check_once(seen: dict, key: tuple, f: Path) -> None:
    if key in seen:
        trajectory, session, run = key
        raise DataError(f"{f}: the same flight as {seen[key]} ({trajectory}, session {session}, run {run}); "
                        "keep one of them")
    seen[key] = f


def _name_of_stem(f: Path) -> tuple[str, int]:
    """Trajectory and run of a file named freely (``Hover 03`` -> ``hover``, 3)."""
    slug = re.sub(r"[^a-z0-9]+", "-", f.stem.lower()).strip("-")
    m = re.match(r"^(?P<t>.*?)-?(?:run)?-?(?P<k>\d+)$", slug)
    trajectory, run = (m["t"].strip("-"), int(m["k"])) if m and m["t"].strip("-") else (slug, 1)
    if not _TRAJECTORY.match(trajectory):
        trajectory = f"flight-{trajectory}" if trajectory else "flight"
    return trajectory, run


def _read_manifest(folder: Path) -> dict[str, tuple[str, str, int, str | None]]:
    """``manifest.csv``: file -> (trajectory, session, run, part); one :class:`DataError` naming
    the row and the field of the first bad value."""
    path = folder / MANIFEST
    try:
        df = pd.read_csv(path, dtype=str, keep_default_na=False, skipinitialspace=True)
    except (pd.errors.EmptyDataError, pd.errors.ParserError, UnicodeDecodeError) as e:
        raise DataError(f"{path}: not a readable CSV file ({e})") from None
    df.columns = [c.strip() for c in df.columns]
    missing = [c for c in ("file", "trajectory", "run") if c not in df.columns]
    if missing:
        raise DataError(f"{path}: missing column(s) {', '.join(map(repr, missing))} (a manifest has columns file, "
                        "trajectory, run, and optionally session and part)")
    out: dict = {}
    for i, row in enumerate(df.to_dict("records")):
        where = f"{path}: row {i + 1} (line {i + 2})"
        file = Path(row["file"].strip()).as_posix()
        trajectory, run = row["trajectory"].strip(), row["run"].strip()
        session, part = row.get("session", "").strip() or "own", row.get("part", "").strip() or None
        if not file or file.startswith("../") or Path(file).is_absolute():
            raise DataError(f"{where}, field 'file': {row['file']!r} is not a path inside {folder}")
        if not _TRAJECTORY.match(trajectory):
            raise DataError(f"{where}, field 'trajectory': {trajectory!r} is not a name (a letter, then letters, "
                            "digits or '-')")
        if not run.isdigit():
            raise DataError(f"{where}, field 'run': {run!r} is not a whole number")
        if not _SESSION.match(session):
            raise DataError(f"{where}, field 'session': {session!r} may not hold '_' or '/'")
        if part not in (None, *PARTS):
            raise DataError(f"{where}, field 'part': {part!r} is neither 'train' nor 'test'")
        if file in out:
            raise DataError(f"{where}, field 'file': {file!r} is listed twice")
        out[file] = (trajectory.lower(), session, int(run), part)
    return out


# distinct samples two flights may share before one counts as a copy of part of the other: a flight
# at rest repeats one sample (one distinct value), a recorded flight never repeats another's
SHARED_SAMPLES = 20
SAME_DECIMALS = 4  # the decimals two samples of one flight agree to, copied by value


def check_distinct(flights: Sequence[Flight]) -> None:
    """Refuse a flight holding samples of another under a different name: a copy, a copy with
    its time stamps moved, or a part of another (its first rows, say); and, by value, a copy
    rounded or rescaled by another tool, or with its positions mirrored (the rotor speeds,
    velocity, attitude and rates, rounded to :data:`SAME_DECIMALS` decimals, the same). A test
    flight in the training set would be trained on and scored on.

    A sample is the row of rotor speeds and outputs; two flights sharing at least
    :data:`SHARED_SAMPLES` distinct samples are refused.
    """
    where = lambda g: str(g.source) if g.source else g.name  # noqa: E731

    def exact(f: Flight) -> np.ndarray:
        return np.column_stack([f.u, f.y])

    def by_value(f: Flight) -> np.ndarray:
        # the sensors' noise is far above 1e-4 in every unit: two flights agreeing to 4 decimals
        # over many samples are one flight; positions left out, so a mirror of one is seen too
        return np.round(np.column_stack([f.u, f.y[:, 3:]]), SAME_DECIMALS) + 0.0  # -0.0 as 0.0

    for rows_of, how in ((exact, "the same samples"),
                         (by_value, f"the same samples to {SAME_DECIMALS} decimals (positions aside)")):
        owner: dict[bytes, int] = {}
        for i, f in enumerate(flights):
            rows = np.ascontiguousarray(rows_of(f), dtype=np.float64)
            keys = set(rows.view(np.dtype((np.void, rows.shape[1] * 8))).ravel().tolist())
            shared: dict[int, int] = {}
            for k in keys:
                j = owner.setdefault(k, i)
                if j != i:
                    shared[j] = shared.get(j, 0) + 1
            j, n = max(shared.items(), key=lambda x: x[1], default=(None, 0))
            if n >= SHARED_SAMPLES:
                a = flights[j]
                raise DataError(f"{where(f)}: {n} of its {len(keys)} distinct samples are {how} as in {where(a)}; a "
                                "flight must be in the data once (a copy under another name, in part, with its time "
                                "moved, rounded, rescaled or mirrored, leaks between training and test)")


def session_of(name: str) -> str:
    """The recording session of a flight: the ``<date>`` of ``<trajectory>_<date>_run<k>``, or the
    name itself where it is not of that form (a flight alone)."""
    m = _NAME.match(name)
    return m["date"] if m else name


def _where(path: Path, column: str, row: int) -> str:
    # row counts data rows from 0; the file line adds the header and 1-based numbering
    return f"{path}: column '{column}', row {row} (line {row + 2})"


def _finite_numbers(path: Path) -> dict[str, np.ndarray] | None:
    """Every column of a CSV whose values are all finite numbers, parsed by pandas' C reader at
    once (correctly rounded, as ``float()``); None when any value is not, or the file is not a
    plain CSV: :func:`_numbers` then reads it column by column to name the first bad value."""
    try:
        df = pd.read_csv(path, dtype=np.float64, keep_default_na=False)
    except (ValueError, UnicodeDecodeError):  # pandas' parser errors are ValueErrors
        return None
    values = {col: df[col].to_numpy(dtype=np.float64, copy=True) for col in df.columns}
    return values if all(np.isfinite(v).all() for v in values.values()) else None


def _numbers(path: Path, col: str, text: pd.Series) -> np.ndarray:
    """The values of column ``col`` read as text, or the :class:`DataError` of its first value
    that is missing, not a number or infinite."""
    raw = text.str.strip()
    num = pd.to_numeric(raw, errors="coerce").to_numpy(dtype=np.float64)
    bad = np.isnan(num)
    if bad.any():
        i = int(np.argmax(bad))
        if raw.iloc[i].lower() in ("", "nan", "na", "null", "none"):
            raise DataError(f"{_where(path, col, i)}: missing value (NaN)")
        raise DataError(f"{_where(path, col, i)}: non-numeric value {raw.iloc[i]!r}")
    inf = ~np.isfinite(num)
    if inf.any():
        i = int(np.argmax(inf))
        raise DataError(f"{_where(path, col, i)}: infinite value {raw.iloc[i]!r}")
    return num


def read_flight_csv(path: str | os.PathLike, *, min_rows: int = 1, name: str | None = None) -> Flight:
    """Read and validate one flight CSV, named ``name`` (default: the file's stem).

    Raises:
        DataError: missing column, non-numeric value, NaN, non-increasing ``t``, a
            quaternion whose norm is off 1 by more than 1e-3, or fewer than ``min_rows``
            rows. The message names the file, the column and the row.
    """
    path = Path(path)
    if path.is_dir():
        raise DataError(f"{path}: a folder, not a flight CSV file")
    if not path.is_file():
        raise DataError(f"{path}: no such file" + (" (a broken link)" if path.is_symlink() else ""))
    values = _finite_numbers(path)
    try:
        df = pd.read_csv(path, dtype=str, keep_default_na=False, nrows=None if values is None else 0)
        with open(path, encoding="utf-8") as fh:
            header = [c.strip() for c in fh.readline().rstrip("\r\n").split(",")]
    except (pd.errors.EmptyDataError, pd.errors.ParserError, UnicodeDecodeError) as e:
        raise DataError(f"{path}: not a readable CSV file ({e})") from None
    twice = sorted({c for c in header if header.count(c) > 1})
    if twice:
        raise DataError(f"{path}: column(s) {', '.join(repr(c) for c in twice)} appear more than once in the header")
    missing = [c for c in SCHEMA if c not in df.columns]
    padded = [c for c in df.columns if c != c.strip() and c.strip() in missing]
    if padded:
        raise DataError(f"{path}: the header's names are padded with spaces ({', '.join(repr(c) for c in padded[:3])}"
                        f"{' ...' if len(padded) > 3 else ''}); write them without (t,m1_rads,...)")
    if missing:
        raise DataError(
            f"{path}: missing column(s) {', '.join(repr(c) for c in missing)}"
            f" (the published schema is: {', '.join(SCHEMA)})"
        )
    if values is None:
        values, text = {}, []
        for col in df.columns:
            try:
                values[col] = _numbers(path, col, df[col])
            except DataError:
                if col in SCHEMA:
                    raise
                text.append(col)  # a note or a label beside the flight: no signal any model reads
        if text:
            log.warning("%s: column(s) %s hold values that are not numbers; left out", path,
                        ", ".join(repr(c) for c in text))
    n = len(next(iter(values.values()))) if values else 0
    if n < min_rows:
        raise DataError(f"{path}: {n} rows, fewer than the {min_rows} one window needs")
    t = values["t"]
    step = np.diff(t)
    step_bad = step <= 0
    if step_bad.any():
        i = int(np.argmax(step_bad)) + 1
        raise DataError(f"{_where(path, 't', i)}: time does not increase ({float(t[i])!r} after {float(t[i - 1])!r})")
    if n > 1:
        median = float(np.median(step))
        if abs(median / SAMPLE_PERIOD - 1) > PERIOD_TOL:
            raise DataError(f"{path}: column 't': samples {median:.6g} s apart ({1 / median:.4g} Hz); the benchmark "
                            f"is sampled at {1 / SAMPLE_PERIOD:g} Hz ({SAMPLE_PERIOD:g} s; is 't' in seconds?)")
        off = np.abs(step / SAMPLE_PERIOD - 1) > PERIOD_TOL
        if off.any():
            i = int(np.argmax(off)) + 1
            what = "a gap" if step[i - 1] >= 1.5 * SAMPLE_PERIOD else "a step"
            raise DataError(f"{_where(path, 't', i)}: {what} of {float(step[i - 1]):.6g} s after {float(t[i - 1])!r} "
                            f"(samples are {SAMPLE_PERIOD:g} s apart, within {PERIOD_TOL:.0%})")
    q = np.stack([values[c] for c in QUAT_COLUMNS], axis=1)
    norm = np.linalg.norm(q, axis=1)
    off = np.abs(norm - 1) > QUAT_NORM_TOL
    if off.any():
        i = int(np.argmax(off))
        raise DataError(
            f"{_where(path, 'qx/qy/qz/qw', i)}: quaternion norm {norm[i]:.6g} is not 1"
            f" (tolerance {QUAT_NORM_TOL:g})"
        )
    return Flight(
        name=name or path.stem,
        t=t,
        u=np.stack([values[c] for c in INPUT_COLUMNS], axis=1),
        y=np.stack([values[c] for c in OUTPUT_COLUMNS], axis=1),
        extra={c: v for c, v in values.items() if c not in ("t", *INPUT_COLUMNS, *OUTPUT_COLUMNS)},
        source=path,
    )


def read_json_record(path: str | os.PathLike, fmt: str, what: str, stage: str) -> dict:
    """A JSON record a stage wrote (``{"format": fmt, ...}``), or one :class:`DataError` naming
    the file and the stage that writes it: missing, not JSON, or of another format."""
    path = Path(path)
    if not path.is_file():
        raise DataError(f"{path}: no {what}; the {stage} stage writes it (dvc repro {stage})")
    try:
        d = json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as e:
        raise DataError(f"{path}: not valid JSON ({e}); rerun the {stage} stage") from None
    if not isinstance(d, dict) or d.get("format") != fmt:
        got = d.get("format") if isinstance(d, dict) else type(d).__name__
        raise DataError(f"{path}: not {what} (field 'format' is {got!r}, expected {fmt!r}); rerun the {stage} stage")
    return d


def check_finite(frame: pd.DataFrame, where: str, *, allowed: Sequence[str] = ()) -> None:
    """Refuse a table about to be written with a NaN or infinite value outside the ``allowed``
    columns (those that mark a missed reading with NaN).

    Raises:
        DataError: naming the table, the column, the first row and how many values.
    """
    for col in frame.columns:
        if col in allowed or not pd.api.types.is_numeric_dtype(frame[col]) or pd.api.types.is_bool_dtype(frame[col]):
            continue
        bad = ~np.isfinite(frame[col].to_numpy(dtype=np.float64))
        if bad.any():
            i = int(np.argmax(bad))
            raise DataError(f"{where}: column {col} holds {int(bad.sum())} value(s) that are not finite (first at row "
                            f"{i}: {frame[col].iloc[i]}); nothing was written")


def write_flight_csv(flight: Flight, path: str | os.PathLike) -> None:
    """Write a flight in the published schema (atomically; same data, same bytes).

    Raises:
        DataError: a value that is not finite (the flight is not written).
    """
    df = flight.to_frame()
    missing = [c for c in SCHEMA if c not in df.columns]
    if missing:
        raise ValueError(f"flight {flight.name}: cannot write, no values for {missing}")
    check_finite(df, f"flight {flight.name} for {path}")
    with atomic_file(path, inputs=[flight.source] if flight.source else ()) as tmp:
        df.to_csv(tmp, index=False, float_format="%.10g", lineterminator="\n")


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


@contextlib.contextmanager
def atomic_file(path: str | os.PathLike, *, inputs: Sequence[str | os.PathLike] = (),
                replace: bool = False) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; rename it onto ``path`` only on success.

    The output guard (:func:`nanosysid.guard.claim`) checks ``path`` first: not an input
    (``inputs`` and the stage's own), not another stage's output, not a file no run of this
    stage wrote (``replace``: a file the project edits in place), one writer at a time. The file
    gets the user's umask (a temporary file is private until then).
    """
    path = Path(path)
    with guard.claim(path, "file", inputs=inputs, replace=replace) as c:
        tmp = c.temporary()
        try:
            yield tmp
            os.chmod(tmp, 0o666 & ~_umask())
            c.done(tmp)
            c.swap(tmp)
        finally:
            if os.path.exists(tmp):
                os.unlink(tmp)


OWNER = guard.OWNER  # the mark of a folder a stage wrote


@contextlib.contextmanager
def atomic_dir(path: str | os.PathLike, *, inputs: Sequence[str | os.PathLike] = ()) -> Iterator[Path]:
    """Yield a temporary directory beside ``path``; swap it in for ``path`` only on success.

    The previous contents of ``path`` stay in place until the new directory is complete, and
    are replaced only if a run of this stage wrote them (:func:`nanosysid.guard.claim`;
    ``inputs`` are inputs beyond the stage's declared ones). The directory gets the user's umask
    and the mark :data:`OWNER`.
    """
    path = Path(path)
    with guard.claim(path, "folder", inputs=inputs) as c:
        tmp = c.temporary()
        try:
            yield tmp
            (tmp / OWNER).write_text(c.mark(tmp))
            os.chmod(tmp, 0o777 & ~_umask())
            c.done(tmp)
            c.swap(tmp)
        finally:
            c.forget(tmp)
            if tmp.exists():
                shutil.rmtree(tmp)


def write_json(path: str | os.PathLike, payload) -> None:
    """``payload`` as strict, indented JSON (:func:`json_text`), written atomically."""
    with atomic_file(Path(path)) as tmp:
        tmp.write_text(json_text(payload))
