"""Same bytes on every x86 machine: the numerical code paths that libraries choose by CPU, pinned.

Floating-point results depend on the order of operations, and each numerical library picks its
kernels by the CPU it finds: torch's element-wise and reduction kernels (portable, AVX2 or
AVX-512), MKL's matrix products under torch, oneDNN, numpy's SIMD loops (``exp``, ``log``,
``sin``, sums) and OpenBLAS under numpy and scipy. Two machines of the same kind then write
different bytes, and a DVC cache shared between them never hits.

:func:`pin` sets each library's own switch to one code path of a level: ``"v2"``, the portable
one that every x86-64 CPU runs, or ``"v3"``, the AVX2 one (x86-64-v3, every x86-64 CPU since
2013-2015), taken where the CPU has it and else ``"v2"``'s. The libraries read these switches
when they are first loaded, so :func:`pin` must run before torch, numpy or scipy is imported:
every stage does so (``stages/__init__.py``, at its stage's level, :data:`STAGE_LEVELS`), as do
the tests and the benchmarks; the Makefile exports the ``"v2"`` environment (``python -m
nanosysid.numerics [v2|v3]`` prints a level's). What is pinned, and what is not, is in the
README ("Reproducibility").
"""

from __future__ import annotations

import contextlib
import os
import platform
import sys
from typing import Iterator

__all__ = ["PINNED", "PINNED_V3", "V3_FLAGS", "LEVELS", "STAGE_LEVELS", "THREADS", "LOOP_THREADS", "pin",
           "pinned_environment", "stage_level", "cpu_flags", "threads", "compiled", "quiet_tracing"]

# Threads split sums (a matrix product's, a reduction's) into partial sums whose order sets the
# last bits: the count is fixed, whatever the machine's cores; NANOSYSID_THREADS changes it (and
# with it the last bits of the outputs that use several). Training has its own count
# (``train.threads``), loops over time on small tensors theirs (:data:`LOOP_THREADS`), numpy's
# and scipy's OpenBLAS one (``OPENBLAS_NUM_THREADS``).
THREADS = os.environ.get("NANOSYSID_THREADS", "2")

PINNED: dict[str, str] = {
    "OMP_NUM_THREADS": THREADS,
    "MKL_NUM_THREADS": THREADS,
    # torch's CPU kernels: the portable build, not the AVX2 or AVX-512 one
    "ATEN_CPU_CAPABILITY": "default",
    # MKL (torch's matrix products): conditional numerical reproducibility, one code path on every x86
    "MKL_CBWR": "COMPATIBLE",
    # oneDNN (some of torch's CPU operators): no instructions beyond SSE4.1
    "ONEDNN_MAX_CPU_ISA": "SSE41",
    # numpy's SIMD loops: the baseline (x86-64-v2) only, none of the dispatched AVX2/AVX-512 ones
    "NPY_DISABLE_CPU_FEATURES": "X86_V3 X86_V4 AVX512_ICL AVX512_SPR",
    # OpenBLAS under numpy and scipy: the Nehalem kernels (SSE4.2), which every x86-64-v2 CPU runs
    "OPENBLAS_CORETYPE": "Nehalem",
    # and one thread: the threads of a threaded matrix product wait for each other by spinning, not
    # sleeping, so beside another busy process (make repro runs two stages on two cores) they take
    # the cores their partners need; the window stage beside the rig's ran 8x slower
    # (benchmarks/blas_threads.py). The count splits some products' sums: other last bits
    "OPENBLAS_NUM_THREADS": "1",
    # inductor's C++ (the simulator's compiled step): the x86-64-v2 instruction set, not the host's
    "TORCHINDUCTOR_CPP_MARCH": "x86-64-v2",
    # OpenMP's idle threads sleep instead of spinning: a switch of speed only (no byte changes),
    # which keeps a thread that waits from taking a core a busy neighbour process needs
    "OMP_WAIT_POLICY": "PASSIVE",
    # OpenBLAS's own threads (numpy's, scipy's) the same: they spin 2^4 cycles for work, not
    # OpenBLAS's default 2^28 (a tenth of a second, on a core a neighbour process needs)
    "OPENBLAS_THREAD_TIMEOUT": "4",
}

# x86-64-v3's instructions as /proc/cpuinfo names them (``abm`` is LZCNT)
V3_FLAGS = frozenset({"avx", "avx2", "bmi1", "bmi2", "f16c", "fma", "abm", "movbe"})

# each library's AVX2 code path, the same on an AVX2 and on an AVX-512 CPU. Its vectorised loops
# give an element other bytes by where it falls in a batch (main loop or tail): what is batched
# over worlds or flights, whose bytes must not depend on the batch, stays on PINNED's
PINNED_V3: dict[str, str] = {
    **PINNED,
    "ATEN_CPU_CAPABILITY": "avx2",
    # MKL's AVX2 code path under conditional numerical reproducibility, and its instructions held
    # to AVX2: a caller's MKL_ENABLE_INSTRUCTIONS (SSE4_2, AVX512) would move it off that path
    "MKL_CBWR": "AVX2",
    "MKL_ENABLE_INSTRUCTIONS": "AVX2",
    "ONEDNN_MAX_CPU_ISA": "AVX2",
    "NPY_DISABLE_CPU_FEATURES": "X86_V4 AVX512_ICL AVX512_SPR",
    "OPENBLAS_CORETYPE": "Haswell",
    # inductor's C++ (phys_res's compiled physics base): x86-64-v3, vectorised for AVX2 (inductor
    # reads ATEN_CPU_CAPABILITY)
    "TORCHINDUCTOR_CPP_MARCH": "x86-64-v3",
}

LEVELS = ("v2", "v3")

# The stages that run at "v3": training, two to three times faster there
# (benchmarks/pinned_level.py). Its batches are the same on every run, so no guarantee ties its
# bytes to a batch; every other stage (the simulator's and the campaign's batches of worlds, the
# evaluations) keeps "v2". The two levels give a trained model other last bits.
STAGE_LEVELS = {"stages.train": "v3"}


# torch's threads inside the library's loops over time on small tensors (the simulator's steps,
# the oracle's rollout): a parallel region over a few hundred numbers costs more than it saves,
# and it stalls whenever another process holds one of the cores. Their bytes are the same on any
# count: each output element is computed in one order (checked by tests/test_numerics.py).
LOOP_THREADS = 1


@contextlib.contextmanager
def threads(n: int) -> Iterator[None]:
    """torch's intra-op thread count set to ``n`` inside the block (or the decorated function),
    the caller's count restored after, whatever it was."""
    import torch  # after pin(): this module is imported before torch

    before = torch.get_num_threads()
    if before == n:
        yield
        return
    torch.set_num_threads(n)
    try:
        yield
    finally:
        torch.set_num_threads(before)


def compiled(fn, *, setting: str, dynamic: bool = False):
    """``torch.compile(fn)`` into the pinned C++ code.

    Inductor fuses a function's tensor operations into a few C++ loops. With
    ``ATEN_CPU_CAPABILITY=default`` they are scalar code, compiled for the pinned x86-64-v2
    (``TORCHINDUCTOR_CPP_MARCH``) without floating-point contraction or unsafe maths (inductor's
    defaults): the same bytes on every x86 machine. They are not the eager function's bytes:
    the two differ by rounding.

    Raises:
        ConfigError: no C++ compiler; the message names ``setting`` (the flag that turns the
            compiled path off).
    """
    import torch
    from torch._inductor.cpp_builder import get_cpp_compiler

    from nanosysid.errors import ConfigError

    try:
        get_cpp_compiler()  # inductor's own search: $CXX, then g++, clang++
    except Exception as e:
        raise ConfigError(f"{setting}: the compiled code needs a C++ compiler ({e}); install g++, or set "
                          f"{setting}=false to run it eagerly") from None
    return torch.compile(fn, dynamic=dynamic)


@contextlib.contextmanager
def quiet_tracing() -> Iterator[None]:
    """Inside the block, dynamo's warning that it traces through a ``functools`` cache is not
    shown: the compiled code reads its constants (the mixer, gravity) through one, which is
    traced once and harmless; and a compiled function may have up to 256 graphs (each batch
    size, set of world effects and user wrench is one), never falling back to the eager code
    (other bytes) past torch's default 8: past 256 it fails."""
    import warnings

    import torch._dynamo.config as dynamo_config

    with warnings.catch_warnings(), dynamo_config.patch(recompile_limit=max(dynamo_config.recompile_limit, 256),
                                                        fail_on_recompile_limit_hit=True):
        warnings.filterwarnings("ignore", message=".*lru_cache.*", category=UserWarning)
        yield


def cpu_flags(cpuinfo: str = "/proc/cpuinfo") -> frozenset[str] | None:
    """The instruction-set flags of this machine's first CPU (None where ``cpuinfo`` cannot be read)."""
    try:
        with open(cpuinfo) as f:
            for line in f:
                if line.startswith("flags"):
                    return frozenset(line.split(":", 1)[1].split())
    except OSError:
        pass
    return None


def pinned_environment(level: str = "v2", *, machine: str | None = None,
                       flags: frozenset[str] | None = None) -> dict[str, str]:
    """The variables :func:`pin` sets for ``level`` on this machine (``machine``, ``flags``:
    another's): :data:`PINNED_V3` for ``"v3"`` where the CPU has every x86-64-v3 instruction,
    else :data:`PINNED` (a CPU without AVX2, flags that cannot be read, or
    ``NANOSYSID_CPU_LEVEL=v2``: one DVC cache shared with such machines); none of the x86
    settings on another architecture.

    Raises:
        ValueError: ``level`` is none of :data:`LEVELS`, or ``NANOSYSID_CPU_LEVEL`` is set to
            something other than ``v2``.
    """
    if level not in LEVELS:
        raise ValueError(f"{level!r}: not a level; the levels are {', '.join(LEVELS)}")
    forced = os.environ.get("NANOSYSID_CPU_LEVEL", "")
    if forced not in ("", "v2"):
        raise ValueError(f"NANOSYSID_CPU_LEVEL={forced}: set v2 (the x86-64-v2 code paths in every stage) or "
                         "leave it unset")
    if (machine or platform.machine()).lower() not in ("x86_64", "amd64"):
        return {k: PINNED[k] for k in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "ATEN_CPU_CAPABILITY", "OMP_WAIT_POLICY",
                                        "OPENBLAS_THREAD_TIMEOUT")}
    flags = cpu_flags() if flags is None else flags
    v3 = level == "v3" and not forced and flags is not None and V3_FLAGS <= flags
    return dict(PINNED_V3 if v3 else PINNED)


def stage_level(argv: list[str] | None = None) -> str:
    """The level of the stage a process was started to run (``argv``: its command line,
    ``sys.orig_argv`` by default; ``python -m stages.train ...`` is ``"v3"``), ``"v2"`` for
    any other process."""
    argv = list(sys.orig_argv if argv is None else argv)
    i = 1
    while i < len(argv) and argv[i].startswith("-") and argv[i] not in ("-", "-c"):  # the interpreter's options
        if argv[i].startswith("-m"):
            module = argv[i][2:] or (argv[i + 1] if i + 1 < len(argv) else "")
            return STAGE_LEVELS.get(module, "v2")
        i += 2 if argv[i] in ("-X", "-W") else 1
    return "v2"


def pin(level: str = "v2") -> None:
    """Set :func:`pinned_environment` of ``level`` in this process's environment, overriding
    what the caller had.

    Raises:
        RuntimeError: torch or numpy is already loaded, so the pin could not take effect.
        SystemExit: ``NANOSYSID_CPU_LEVEL`` is no level (its message says which are).
    """
    try:
        env = pinned_environment(level)
    except ValueError as e:
        raise SystemExit(f"error: {e}") from None
    late = [m for m in ("torch", "numpy") if m in sys.modules]
    if late and any(os.environ.get(k) != v for k, v in env.items()):
        raise RuntimeError(f"nanosysid.numerics.pin() runs after {' and '.join(late)} was imported; "
                           "it must run first for the pinned code paths to take effect")
    os.environ.update(env)


if __name__ == "__main__":
    try:
        print(" ".join(f"{k}='{v}'" for k, v in pinned_environment(*sys.argv[1:2]).items()))
    except ValueError as e:
        raise SystemExit(f"error: {e}") from None
