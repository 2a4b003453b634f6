"""Same bytes on every x86 machine: the numerical code paths that libraries choose by CPU, pinned.

Floating-point results depend on the order of operations, and each numerical library picks its
kernels by the CPU it finds: torch's element-wise and reduction kernels (portable, AVX2 or
AVX-512), MKL's matrix products under torch, oneDNN, numpy's SIMD loops (``exp``, ``log``,
``sin``, sums) and OpenBLAS under numpy and scipy. Two machines of the same kind then write
different bytes, and a DVC cache shared between them never hits.

:func:`pin` sets each library's own switch to one code path that every x86-64 CPU runs. The
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

__all__ = ["PINNED", "THREADS", "LOOP_THREADS", "pin", "pinned_environment", "threads", "compiled", "quiet_tracing"]

# Threads split sums (a matrix product's, a reduction's) into partial sums whose order sets the
# last bits: the count is fixed, whatever the machine's cores; NANOSYSID_THREADS changes it (and
# with it the last bits of the outputs that use several). Training has its own count
# (``train.threads``), loops over time on small tensors theirs (:data:`LOOP_THREADS`).
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
    # inductor's C++ (the simulator's compiled step): the x86-64-v2 instruction set, not the host's
    "TORCHINDUCTOR_CPP_MARCH": "x86-64-v2",
    # OpenMP's idle threads sleep instead of spinning: a switch of speed only (no byte changes),
    # which keeps a thread that waits from taking a core a busy neighbour process needs
    "OMP_WAIT_POLICY": "PASSIVE",
    # OpenBLAS's own threads (numpy's, scipy's) the same: they spin 2^4 cycles for work, not
    # OpenBLAS's default 2^28 (a tenth of a second, on a core a neighbour process needs)
    "OPENBLAS_THREAD_TIMEOUT": "4",
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


def pinned_environment() -> dict[str, str]:
    """The variables :func:`pin` sets on this machine (none of the x86 ones elsewhere)."""
    if platform.machine().lower() not in ("x86_64", "amd64"):
        return {k: PINNED[k] for k in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "ATEN_CPU_CAPABILITY", "OMP_WAIT_POLICY",
                                        "OPENBLAS_THREAD_TIMEOUT")}
    return dict(PINNED)


def pin() -> None:
    """Set :data:`PINNED` in this process's environment, overriding what the caller had.

    Raises:
        RuntimeError: torch or numpy is already loaded, so the pin could not take effect.
    """
    env = pinned_environment()
    late = [m for m in ("torch", "numpy") if m in sys.modules]
    if late and any(os.environ.get(k) != v for k, v in env.items()):
        raise RuntimeError(f"nanosysid.numerics.pin() runs after {' and '.join(late)} was imported; "
                           "it must run first for the pinned code paths to take effect")
    os.environ.update(env)


if __name__ == "__main__":
    print(" ".join(f"{k}='{v}'" for k, v in pinned_environment().items()))
