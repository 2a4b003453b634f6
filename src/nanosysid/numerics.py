"""Same bytes on every x86 machine of a level: the numerical code paths that libraries choose by CPU, pinned.

Floating-point results depend on the order of operations, and each numerical library picks its
kernels by the CPU it finds: torch's element-wise and reduction kernels (portable, AVX2 or
AVX-512), MKL's matrix products under torch, oneDNN, numpy's SIMD loops (``exp``, ``log``,
``sin``, sums) and OpenBLAS under numpy and scipy. Two machines of the same kind then write
different bytes, and a DVC cache shared between them never hits.

:func:`pin` sets each library's own switch to one code path: AVX2 (x86-64-v3, every x86-64 CPU
since 2013-2015) where the CPU has it, else the x86-64-v2 one (``NANOSYSID_CPU_LEVEL=v2``: that
one everywhere). The AVX2 paths train a learned model several times faster than the scalar ones
(``benchmarks/pinned_level.py``); the two levels give other last bits, so a shared DVC cache
hits between machines of one level. The
libraries read these switches when they are first loaded, so :func:`pin` must run before torch,
numpy or scipy is imported: every stage does so (``stages/__init__.py``), as do the tests and
the benchmarks; the Makefile exports the same environment (``python -m nanosysid.numerics``
prints it). What is pinned, and what is not, is in the README ("Reproducibility").
"""

from __future__ import annotations

import contextlib
import os
import platform
import sys
from typing import Iterator

__all__ = ["PINNED", "PINNED_V2", "V3_FLAGS", "LEVELS", "THREADS", "LOOP_THREADS", "pin", "pinned_environment", "cpu_flags",
           "threads", "compiled", "quiet_tracing"]

# Threads split sums (a matrix product's, a reduction's) into partial sums whose order sets the
# last bits: the count is fixed, whatever the machine's cores; NANOSYSID_THREADS changes it (and
# with it the last bits of the outputs that use several). Training has its own count
# (``train.threads``), loops over time on small tensors theirs (:data:`LOOP_THREADS`).
THREADS = os.environ.get("NANOSYSID_THREADS", "2")

# x86-64-v3's instructions as /proc/cpuinfo names them (``abm`` is LZCNT)
V3_FLAGS = frozenset({"avx", "avx2", "bmi1", "bmi2", "f16c", "fma", "abm", "movbe"})

# each library's AVX2 code path: the same on an AVX2 and an AVX-512 CPU
PINNED: dict[str, str] = {
    "OMP_NUM_THREADS": THREADS,
    "MKL_NUM_THREADS": THREADS,
    # torch's CPU kernels: the AVX2 build, not the portable or the AVX-512 one
    "ATEN_CPU_CAPABILITY": "avx2",
    # MKL (torch's matrix products): conditional numerical reproducibility, its AVX2 code path;
    # and its instructions held to AVX2, since a caller's MKL_ENABLE_INSTRUCTIONS (SSE4_2, AVX512)
    # would otherwise move it off that path
    "MKL_CBWR": "AVX2",
    "MKL_ENABLE_INSTRUCTIONS": "AVX2",
    # oneDNN (some of torch's CPU operators): no instructions beyond AVX2
    "ONEDNN_MAX_CPU_ISA": "AVX2",
    # numpy's SIMD loops: up to x86-64-v3 (AVX2, FMA), none of the AVX-512 ones
    "NPY_DISABLE_CPU_FEATURES": "X86_V4 AVX512_ICL AVX512_SPR",
    # OpenBLAS under numpy and scipy: the Haswell kernels (AVX2, FMA)
    "OPENBLAS_CORETYPE": "Haswell",
    # inductor's C++ (the simulator's compiled step, a physics base in training): the x86-64-v3
    # instruction set, not the host's; vectorised for AVX2 (inductor reads ATEN_CPU_CAPABILITY)
    "TORCHINDUCTOR_CPP_MARCH": "x86-64-v3",
    # OpenMP's idle threads sleep instead of spinning: a switch of speed only (no byte changes),
    # which keeps a thread that waits from taking a core a busy neighbour process needs
    "OMP_WAIT_POLICY": "PASSIVE",
    # OpenBLAS's own threads (numpy's, scipy's) the same: they spin 2^4 cycles for work, not
    # OpenBLAS's default 2^28 (a tenth of a second, on a core a neighbour process needs)
    "OPENBLAS_THREAD_TIMEOUT": "4",
}

# a CPU without AVX2: the scalar code paths that every x86-64-v2 CPU runs (other last bits)
PINNED_V2: dict[str, str] = {
    **{k: v for k, v in PINNED.items() if k != "MKL_ENABLE_INSTRUCTIONS"},
    "ATEN_CPU_CAPABILITY": "default",
    "MKL_CBWR": "COMPATIBLE",
    "ONEDNN_MAX_CPU_ISA": "SSE41",
    "NPY_DISABLE_CPU_FEATURES": "X86_V3 X86_V4 AVX512_ICL AVX512_SPR",
    "OPENBLAS_CORETYPE": "Nehalem",
    "TORCHINDUCTOR_CPP_MARCH": "x86-64-v2",
}


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

    Inductor fuses a function's tensor operations into a few C++ loops, vectorised for the
    pinned ``ATEN_CPU_CAPABILITY`` (AVX2; scalar where it is ``default``) and compiled for the
    pinned instruction set (``TORCHINDUCTOR_CPP_MARCH``) without floating-point contraction or
    unsafe maths (inductor's defaults): the same bytes on every x86 machine of that level. They
    are not the eager function's bytes: the two differ by rounding.

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


# NANOSYSID_CPU_LEVEL=v2 pins the x86-64-v2 paths on any x86 CPU: one DVC cache shared with
# machines without AVX2 (the AVX2 paths are never forced: on a CPU without them they would crash)
LEVELS = ("", "auto", "v2")


def pinned_environment(machine: str | None = None, flags: frozenset[str] | None = None,
                       level: str | None = None) -> dict[str, str]:
    """The variables :func:`pin` sets on this machine (``machine``, ``flags``, ``level``: another's,
    the last ``NANOSYSID_CPU_LEVEL`` by default): the AVX2 paths where the CPU has every
    x86-64-v3 instruction, the x86-64-v2 ones where it lacks one, its flags cannot be read or
    ``level`` is ``"v2"``, none of the x86 ones elsewhere.

    Raises:
        ValueError: ``level`` is none of :data:`LEVELS`.
    """
    level = os.environ.get("NANOSYSID_CPU_LEVEL", "") if level is None else level
    if level not in LEVELS:
        raise ValueError(f"NANOSYSID_CPU_LEVEL={level}: not a level; set v2 (the x86-64-v2 code paths, on any x86 "
                         "CPU) or leave it unset (AVX2 where the CPU has it)")
    machine = (machine or platform.machine()).lower()
    if machine not in ("x86_64", "amd64"):
        return {k: PINNED_V2[k] for k in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "ATEN_CPU_CAPABILITY", "OMP_WAIT_POLICY",
                                           "OPENBLAS_THREAD_TIMEOUT")}
    flags = cpu_flags() if flags is None else flags
    v3 = level != "v2" and flags is not None and V3_FLAGS <= flags
    return dict(PINNED if v3 else PINNED_V2)


def pin() -> None:
    """Set :func:`pinned_environment` in this process's environment, overriding what the caller had.

    Raises:
        RuntimeError: torch or numpy is already loaded, so the pin could not take effect.
        SystemExit: ``NANOSYSID_CPU_LEVEL`` is no level (its message says which are).
    """
    try:
        env = pinned_environment()
    except ValueError as e:
        raise SystemExit(f"error: {e}") from None
    late = [m for m in ("torch", "numpy") if m in sys.modules]
    if late and any(os.environ.get(k) != v for k, v in env.items()):
        raise RuntimeError(f"nanosysid.numerics.pin() runs after {' and '.join(late)} was imported; "
                           "it must run first for the pinned code paths to take effect")
    os.environ.update(env)


if __name__ == "__main__":
    try:
        print(" ".join(f"{k}='{v}'" for k, v in pinned_environment().items()))
    except ValueError as e:
        raise SystemExit(f"error: {e}") from None
