"""A stage never writes a value that is not finite as a result: the flight tables, the
extracted streams and the templates are checked as they are written, and nothing is left."""

from __future__ import annotations

import dataclasses

import numpy as np
import pandas as pd
import pytest

from nanosysid.dataio import check_finite, write_flight_csv
from nanosysid.errors import DataError
from nanosysid.synthetic import synthetic_flights

CLASS = "wrong result written"


@pytest.fixture(scope="module")
def flight():
    return synthetic_flights(["square_20250101_run1"], 80, seed=5)[0]


def spoil_y(col, value):
    def f(fl):
        y = fl.y.copy()
        y[17, col] = value
        return dataclasses.replace(fl, y=y)
    return f


def spoil_u(value):
    def f(fl):
        u = fl.u.copy()
        u[:, 2] = value  # a whole column, as a filter fed a stream of NaN writes
        return dataclasses.replace(fl, u=u)
    return f


def spoil_extra(value):
    def f(fl):
        extra = {k: v.copy() for k, v in fl.extra.items()}
        key = sorted(extra)[0]
        extra[key][5] = value
        return dataclasses.replace(fl, extra=extra)
    return f


CASES = [
    ("a NaN velocity", spoil_y(3, np.nan), None),
    ("an infinite position", spoil_y(0, np.inf), None),
    ("a quaternion component of -inf", spoil_y(8, -np.inf), None),
    ("a motor column of NaN", spoil_u(np.nan), None),
    ("a NaN acceleration", spoil_extra(np.nan), None),
]


@pytest.mark.parametrize("case,spoil,_", CASES, ids=[c[0] for c in CASES])
def test_a_flight_with_a_value_that_is_not_finite_is_not_written(flight, tmp_path, case, spoil, _):
    out = tmp_path / "flights" / f"{flight.name}.csv"
    with pytest.raises(DataError, match=rf"flight {flight.name} for .*: column \S+ holds \d+ value\(s\) that are not "
                                        r"finite \(first at row \d+: .*\); nothing was written"):
        write_flight_csv(spoil(flight), out)
    assert not out.exists() and not any(out.parent.glob("*")) if out.parent.exists() else True


def test_marked_missing_readings_may_be_nan_where_allowed():
    frame = pd.DataFrame({"t_src": [0.0, 0.01], "m1": [np.nan, 1.0], "armed": [True, True]})
    check_finite(frame, "motors", allowed=["m1"])
    with pytest.raises(DataError, match=r"motors: column m1 holds 1 value\(s\) that are not finite \(first at row 0"):
        check_finite(frame, "motors")
