"""Same bytes whatever the CPU's kernel level, BLAS dispatch and thread count: the stages pin
the numerical code paths (:mod:`nanosysid.numerics`)."""

import hashlib
import os
import subprocess
import sys
from pathlib import Path

import pytest

from nanosysid import numerics
from test_pipeline import TINY_SIM, tiny_args  # noqa: F401  (TINY_SIM is part of tiny_args)

ROOT = Path(__file__).resolve().parents[1]
STAGES = ["simulate", "extract", "sync", "filter", "split"]
# the simulator's compiled step, whose inductor code the pinned instruction set holds to one path
COMPILED = ["sim.flight.compile=true"]


def run_stages(root: Path, env: dict) -> subprocess.Popen:
    """The stages one after another in one process started with ``env`` (a stage pins the code
    paths where its package is first imported, as each of DVC's stage processes does), then the
    residual model's training as DVC runs it, ``python -m stages.train`` (at its own level)."""
    script = "\n".join([
        "import importlib, os, subprocess, sys",
        "caller = dict(os.environ)  # before a stage's pin changes it",
        "from stages.common import run_stage",
        f"for stage in {STAGES!r}:",
        "    main = importlib.import_module(f'stages.{stage}').main",
        f"    if run_stage(main, description='', argv={tiny_args(root, *COMPILED)!r}):",
        "        sys.exit(f'stage {stage} failed')",
        f"train = [sys.executable, '-m', 'stages.train', 'residual', *{tiny_args(root, *COMPILED)!r}]",
        "sys.exit(subprocess.run(train, env=caller).returncode)",
    ])
    return subprocess.Popen([sys.executable, "-c", script], cwd=ROOT, env=env, stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE, text=True)


def digests(root: Path) -> dict[str, str]:
    return {str(p.relative_to(root)): hashlib.md5(p.read_bytes()).hexdigest()
            for p in sorted(root.rglob("*")) if p.is_file() and p.name != "params.yaml"}


@pytest.mark.slow
def test_simulate_sync_and_train_give_the_same_bytes_under_other_cpu_settings(tmp_path, venv_env):
    variants = {
        # a caller whose torch would pick AVX2 kernels, MKL limited to AVX2, one thread
        "a": {"ATEN_CPU_CAPABILITY": "avx2", "MKL_ENABLE_INSTRUCTIONS": "AVX2", "OMP_NUM_THREADS": "1"},
        # the machine's own best kernels, AVX-512 where it has them, numpy's SIMD loops, more threads
        "b": {"ATEN_CPU_CAPABILITY": "avx512", "MKL_ENABLE_INSTRUCTIONS": "AVX512", "OMP_NUM_THREADS": "4",
              "NPY_DISABLE_CPU_FEATURES": "", "OPENBLAS_CORETYPE": "Haswell", "TORCHINDUCTOR_CPP_MARCH": "native"},
    }
    procs = {}
    for k, extra in variants.items():
        (tmp_path / k).mkdir()
        procs[k] = run_stages(tmp_path / k, {**venv_env, **extra})
    for k, p in procs.items():
        _, err = p.communicate(timeout=900)
        assert p.returncode == 0, err[-2000:]
    a, b = digests(tmp_path / "a"), digests(tmp_path / "b")
    assert any(f.startswith("raw/") for f in a) and any(f.startswith("sync/") for f in a)
    assert "models/residual/model.pt" in a
    assert a == b, sorted(f for f in a if a[f] != b.get(f))


def test_a_stage_runs_the_portable_kernels_whatever_the_caller_asked(venv_env):
    code = "import stages, torch; print(torch.backends.cpu.get_cpu_capability(), torch.get_num_threads())"
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, check=True,
                         env={**venv_env, "ATEN_CPU_CAPABILITY": "avx2", "OMP_NUM_THREADS": "7"}).stdout.split()
    assert out == ["DEFAULT", os.environ.get("NANOSYSID_THREADS", "2")]


@pytest.mark.parametrize("argv, level", [
    (["python", "-m", "stages.train", "lstm", "--params", "params-rig.yaml"], "v3"),
    (["python", "-X", "dev", "-mstages.train", "phys_res"], "v3"),
    (["python", "-m", "stages.evaluate", "lstm"], "v2"),
    (["python", "-m", "nanosysid.repro", "--jobs", "2"], "v2"),
    (["python", "-m", "pytest", "-m", "stages.train"], "v2"),  # pytest's marker option, not the interpreter's
    (["python", "-c", "import stages", "-m", "stages.train"], "v2"),
    (["python", "script.py", "-m", "stages.train"], "v2"),
])
def test_only_the_train_stage_runs_at_the_avx2_level(argv, level):
    assert numerics.stage_level(argv) == level


def test_the_avx2_level_falls_back_to_the_portable_one_where_the_cpu_or_the_user_says_so(monkeypatch):
    monkeypatch.delenv("NANOSYSID_CPU_LEVEL", raising=False)
    v3 = frozenset({"sse4_2", "avx", "avx2", "bmi1", "bmi2", "f16c", "fma", "abm", "movbe"})
    assert numerics.pinned_environment("v3", machine="x86_64", flags=v3)["ATEN_CPU_CAPABILITY"] == "avx2"
    # a Sandy Bridge: AVX without AVX2, FMA or BMI
    assert numerics.pinned_environment("v3", machine="x86_64", flags=frozenset({"sse4_2", "avx"})) == numerics.PINNED
    assert numerics.pinned_environment("v2", machine="x86_64", flags=v3) == numerics.PINNED
    monkeypatch.setenv("NANOSYSID_CPU_LEVEL", "v2")
    assert numerics.pinned_environment("v3", machine="x86_64", flags=v3) == numerics.PINNED
    monkeypatch.setenv("NANOSYSID_CPU_LEVEL", "v4")
    with pytest.raises(ValueError, match="NANOSYSID_CPU_LEVEL=v4"):
        numerics.pinned_environment("v3", machine="x86_64", flags=v3)


@pytest.mark.skipif(not numerics.V3_FLAGS <= (numerics.cpu_flags() or frozenset()), reason="no AVX2 on this CPU")
def test_the_avx2_level_runs_torchs_avx2_kernels_whatever_the_caller_asked(venv_env):
    code = ("from nanosysid import numerics; numerics.pin('v3'); import torch; "
            "print(torch.backends.cpu.get_cpu_capability(), torch.get_num_threads())")
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, check=True,
                         env={**venv_env, "ATEN_CPU_CAPABILITY": "avx512", "MKL_ENABLE_INSTRUCTIONS": "SSE4_2",
                              "OMP_NUM_THREADS": "7"}).stdout.split()
    assert out == ["AVX2", os.environ.get("NANOSYSID_THREADS", "2")]


def test_the_simulators_loop_runs_on_one_thread_with_the_bytes_of_two_and_gives_the_count_back(monkeypatch):
    import numpy as np
    import torch

    import nanosysid.sim.simulator as simulator
    from nanosysid import sim

    specs = [sim.FlightSpec("chirp", 1, effects=None, seed=3), sim.FlightSpec("chirp", 2, effects={}, seed=4)]
    # the eager step: a spy inside the compiled one would run once, when it is traced
    cfg = sim.SimConfig.from_mapping({"preroll": 0.5, "compile": False, "trajectories": {"chirp": {"duration": 1.0}}})
    seen = []
    real = simulator.Nature.wrench

    def spy(self, *a, **k):
        seen.append(torch.get_num_threads())
        return real(self, *a, **k)

    before = torch.get_num_threads()
    torch.set_num_threads(2)
    try:
        with monkeypatch.context() as m:
            m.setattr(simulator.Nature, "wrench", spy)
            ours = simulator.simulate_raw(specs, cfg=cfg, progress=False)
        assert seen and set(seen) == {1} and torch.get_num_threads() == 2
        two = simulator.simulate_raw.__wrapped__(specs, cfg=cfg, progress=False)  # the loop on two threads
    finally:
        torch.set_num_threads(before)
    for name in ("x", "omega", "omega_dot", "wrench"):
        assert np.array_equal(getattr(ours, name), getattr(two, name)), name
