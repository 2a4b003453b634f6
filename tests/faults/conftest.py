"""The hostile-input matrix: each module names the class of fault it tries (``CLASS``); a full
run of the matrix records the number of cases per class and how many ended as they must in
``tests/faults/record.json``, from which the README's reliability section is generated
(``python -m nanosysid.report.readme --sections reliability``). A partial run (``-k``, one
file) records nothing."""

from __future__ import annotations

import json
from collections import Counter
from pathlib import Path

import pytest

from nanosysid import config

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]
RECORD = HERE / "record.json"
_outcomes: dict[str, str] = {}
_classes: dict[str, str] = {}
_partial = False


def pytest_collection_modifyitems(session, config, items):
    for item in items:
        if HERE in Path(str(item.fspath)).parents:
            _classes[item.nodeid] = getattr(item.module, "CLASS", "other")


def pytest_deselected(items):
    global _partial
    if any(HERE in Path(str(i.fspath)).parents for i in items):
        _partial = True


def pytest_runtest_logreport(report):
    if report.nodeid not in _classes:
        return
    if report.when == "call" or report.outcome != "passed":
        # a failure in setup or teardown counts against the case too
        if _outcomes.get(report.nodeid) != "failed":
            _outcomes[report.nodeid] = report.outcome


def pytest_sessionfinish(session, exitstatus):
    ran = set(_outcomes)
    if _partial or not _classes or ran != set(_classes) or len(list(HERE.glob("test_*.py"))) != len(
            {n.split("::")[0] for n in _classes}):
        return
    cases, passed = Counter(), Counter()
    for nodeid, cls in _classes.items():
        cases[cls] += 1
        passed[cls] += _outcomes[nodeid] == "passed"
    record = {"format": "nanosysid-faults-1",
              "classes": {c: {"cases": cases[c], "as_they_must": passed[c]} for c in sorted(cases)},
              "cases": sum(cases.values()), "as_they_must": sum(passed.values())}
    text = json.dumps(record, indent=1, sort_keys=True) + "\n"
    if not RECORD.exists() or RECORD.read_text() != text:
        RECORD.write_text(text)


@pytest.fixture(scope="session")
def params(tmp_path_factory):
    """``params.yaml`` composed from ``conf/`` (the committed one may be stale while conf/ is edited)."""
    path = tmp_path_factory.mktemp("params") / "params.yaml"
    config.compose([], out=path, conf_dir=ROOT / "conf")
    return path
