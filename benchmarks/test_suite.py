"""Time of `make test` in a fresh clone of this repository's last commit, the virtual environment
built there as a new user's is, against the tests' own summed time in the same run.

The clone builds its own ``.venv`` (``make venv``, timed apart) and runs ``make test`` with it.
The summed time is pytest's per-test time (setup, call and teardown) over both workers: summed
over wall time is how well the two workers overlap, at most 2. A failing suite gives no figures.
"""

from __future__ import annotations

import os
import subprocess
import tempfile
import time
import xml.etree.ElementTree as ET
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def main() -> dict[str, float]:
    with tempfile.TemporaryDirectory(prefix="nanosysid-suite-") as tmp:
        clone, report = Path(tmp) / "clone", Path(tmp) / "junit.xml"
        subprocess.run(["git", "clone", "--quiet", str(ROOT), str(clone)], check=True)
        env = {k: v for k, v in os.environ.items() if k not in ("VIRTUAL_ENV", "PYTHONPATH")}
        t0 = time.perf_counter()
        if subprocess.run(["make", "venv"], cwd=clone, env=env, stdout=subprocess.DEVNULL).returncode != 0:
            raise SystemExit("make venv failed in the clone: no figures")
        build = time.perf_counter() - t0
        env["PYTEST_ADDOPTS"] = f"--junitxml={report} -o junit_duration_report=total"
        t0 = time.perf_counter()
        rc = subprocess.run(["make", "test"], cwd=clone, env=env).returncode
        wall = time.perf_counter() - t0
        if rc != 0:
            raise SystemExit(f"make test failed in the clone (exit {rc}): no figures")
        suite = ET.parse(report).getroot()
        suite = suite if suite.tag == "testsuite" else suite.find("testsuite")
        busy = sum(float(case.get("time", 0.0)) for case in suite.iter("testcase"))
        skipped = int(suite.get("skipped", 0))
        passed = int(suite.get("tests", 0)) - skipped - int(suite.get("failures", 0)) - int(suite.get("errors", 0))
    print(f"environment build: {build:.1f} s; make test: {wall:.1f} s, {passed} passed, {skipped} skipped; "
          f"in all {build + wall:.1f} s; tests' summed time {busy:.1f} s")
    return {"fresh_clone_s": build + wall, "environment_build_s": build, "make_test_s": wall, "tests_summed_s": busy,
            "summed_over_wall": busy / wall, "passed": passed, "skipped": skipped}


if __name__ == "__main__":
    main()
