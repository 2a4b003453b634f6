"""A model's generated C on an emulated STM32F405: build, run, check, count.

The firmware (``firmware/``: start-up code, linker script, a ``main`` that runs the step on
inputs from a test flight) is built with ``arm-none-eabi-gcc`` for the Cortex-M4F (hard
float, ``-O2``) and run on QEMU's ``netduinoplus2`` machine with semihosting for its output.
A small TCG plugin, built here from ``firmware/icount.c``, counts the instructions executed
between two marker calls around each step. ``arm-none-eabi-size`` gives the flash and RAM
of the model's own object file; ``-fstack-usage`` the stack of its step.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from nanosysid.errors import ToolchainError
from nanosysid.export import CLOCK_HZ, MAX_CYCLES_PER_INSTRUCTION
from nanosysid.export.cgen import flit
from nanosysid.export.csource import CModel

__all__ = ["ToolchainError", "require_toolchain", "range_relative_diff", "write_sources", "build", "run", "McuRun",
           "CFLAGS", "CLOCK_HZ", "INSTALL_HINT", "MAX_CYCLES_PER_INSTRUCTION", "graph_operators"]

FIRMWARE = Path(__file__).with_name("firmware")
# fused multiply-adds (vfma) as GNU C would contract them; -std=c99 alone turns contraction off
CFLAGS = ["-mcpu=cortex-m4", "-mthumb", "-mfloat-abi=hard", "-mfpu=fpv4-sp-d16", "-O2", "-std=c99", "-ffp-contract=fast",
          "-Wall", "-Wextra", "-Werror", "-ffunction-sections", "-fdata-sections"]
TOOLS = {"arm-none-eabi-gcc": "gcc-arm-none-eabi", "arm-none-eabi-size": "binutils-arm-none-eabi",
         "arm-none-eabi-nm": "binutils-arm-none-eabi", "qemu-system-arm": "qemu-system-arm", "gcc": "gcc"}
INSTALL_HINT = ("apt-get install -y --no-install-recommends gcc-arm-none-eabi libnewlib-arm-none-eabi "
                "qemu-system-arm gcc libc6-dev   (as root; `make toolchain` does it)")


def graph_operators(onnx_path: Path) -> int:
    """The operators of an exported ONNX graph that compute (its constants left out): what a
    graph runtime dispatches one by one, where the generated C runs straight through."""
    import onnx

    return sum(1 for node in onnx.load(str(onnx_path)).graph.node if node.op_type != "Constant")


def range_relative_diff(got: np.ndarray, ref: np.ndarray, samples: np.ndarray) -> float:
    """Largest ``|got - ref|`` of an output channel over that channel's range (max - min) in
    ``samples`` (N, ny), e.g. the test flight: an output far from zero (z near 1.5 m, qw near 1)
    is judged on its variation, not on its offset."""
    span = samples.max(axis=0) - samples.min(axis=0)
    span = np.where(span > 0, span, 1.0)  # a channel that never moves is judged in its own units
    return float((np.abs(np.asarray(got, np.float64) - ref) / span).max())


def require_toolchain() -> None:
    """Raise :class:`ToolchainError` naming each missing tool and the command that installs it."""
    missing = [t for t in TOOLS if shutil.which(t) is None]
    newlib = Path("/usr/lib/arm-none-eabi/newlib").exists() or Path("/usr/lib/arm-none-eabi/lib").exists()
    if not newlib:
        missing.append("newlib for arm-none-eabi")
    if missing:
        raise ToolchainError(f"missing {', '.join(missing)}: install them with\n    {INSTALL_HINT}")


def _c_matrix(name: str, a: np.ndarray) -> str:
    rows = ",\n    ".join("{" + ", ".join(flit(v) for v in r) + "}" for r in np.asarray(a, dtype=np.float32))
    return f"static const float {name}[{a.shape[0]}][{a.shape[1]}] = {{\n    {rows}\n}};\n"


def write_sources(out: Path, model: CModel, y_in: np.ndarray, u_in: np.ndarray) -> None:
    """The firmware's sources in ``out``: the model, its header, the inputs and the fixed files."""
    out.mkdir(parents=True, exist_ok=True)
    (out / "nsi_model.h").write_text(model.header)
    (out / "model.c").write_text(model.source)
    (out / "nsi_inputs.h").write_text(
        f"/* {len(y_in)} steps of inputs from a test flight */\n#define NSI_K {len(y_in)}\n"
        + _c_matrix("nsi_y_in", y_in) + _c_matrix("nsi_u_in", u_in))
    for f in ("main.c", "startup.c", "stm32f405.ld", "icount.c"):
        shutil.copyfile(FIRMWARE / f, out / f)


def _run(cmd: list[str], cwd: Path, timeout: float = 120) -> subprocess.CompletedProcess:
    r = subprocess.run(cmd, cwd=cwd, capture_output=True, text=True, timeout=timeout)
    if r.returncode != 0:
        raise RuntimeError(f"{' '.join(map(str, cmd))} failed in {cwd} (exit {r.returncode}):\n{r.stderr[-3000:]}")
    return r


def build(out: Path) -> dict[str, int]:
    """Build ``firmware.elf`` and the plugin in ``out``; sizes of the model's object file.

    Returns ``text``, ``data``, ``bss`` (bytes, ``arm-none-eabi-size``) and ``stack`` (bytes
    of ``nsi_step``'s frame and the frames of the model's functions it calls)."""
    require_toolchain()
    _run(["arm-none-eabi-gcc", *CFLAGS, "-fstack-usage", "-c", "model.c", "-o", "model.o"], out)
    _run(["arm-none-eabi-gcc", *CFLAGS, "--specs=rdimon.specs", "-nostartfiles", "-T", "stm32f405.ld",
          "-Wl,--gc-sections", "-o", "firmware.elf", "startup.c", "main.c", "model.o", "-lm"], out)
    _run(["gcc", "-shared", "-fPIC", "-O2", "-fvisibility=hidden", "-o", "libicount.so", "icount.c"], out)
    size = _run(["arm-none-eabi-size", "model.o"], out).stdout.splitlines()[1].split()
    frames = {m.group(1): int(m.group(2)) for m in
              re.finditer(r":(\w+)\s+(\d+)\s+\w+", (out / "model.su").read_text())}
    # nsi_step calls at most one helper at a time: its frame plus the deepest helper's
    helpers = [v for k, v in frames.items() if k not in ("nsi_step", "nsi_init")]
    stack = frames.get("nsi_step", 0) + max(helpers, default=0)
    return {"text": int(size[0]), "data": int(size[1]), "bss": int(size[2]), "stack": stack}


@dataclass
class McuRun:
    """Outputs of the firmware ``(K, ny)`` and its instruction counts."""

    outputs: np.ndarray
    instructions_per_step: float
    instructions_total: int
    steps: int


def _symbol(out: Path, name: str) -> int:
    for line in _run(["arm-none-eabi-nm", "firmware.elf"], out).stdout.splitlines():
        parts = line.split()
        if len(parts) == 3 and parts[2] == name:
            return int(parts[0], 16) & ~1  # the Thumb bit is not part of the address
    raise RuntimeError(f"{out / 'firmware.elf'}: no symbol {name}")


def run(out: Path, ny: int, *, timeout: float = 120) -> McuRun:
    """Run ``firmware.elf`` on ``qemu-system-arm -M netduinoplus2``; parse outputs and counts."""
    out = Path(out).resolve()
    begin, end = _symbol(out, "nsi_mark_begin"), _symbol(out, "nsi_mark_end")
    log = out / "icount.log"
    cmd = ["qemu-system-arm", "-M", "netduinoplus2", "-nographic", "-monitor", "none", "-serial", "none",
           "-semihosting-config", "enable=on,target=native", "-icount", "shift=0",
           "-plugin", f"{out / 'libicount.so'},begin={begin:#x},end={end:#x}", "-d", "plugin", "-D", str(log),
           "-kernel", "firmware.elf"]
    env = {**os.environ, "LC_ALL": "C"}
    r = subprocess.run(cmd, cwd=out, capture_output=True, text=True, timeout=timeout, env=env)
    if r.returncode != 0:
        raise RuntimeError(f"QEMU exited with {r.returncode} running {out / 'firmware.elf'}:\n{r.stderr[-2000:]}")
    lines = r.stdout.split()
    if not lines or lines[-2] != "done":
        raise RuntimeError(f"{out / 'firmware.elf'}: the firmware did not finish; output ends {r.stdout[-300:]!r}")
    k = int(lines[-1])
    values = np.array(lines[:-2], dtype=np.float64).reshape(k, ny)
    m = re.search(r"icount total=(\d+) marked=(\d+) pairs=(\d+)", log.read_text())
    if m is None:
        raise RuntimeError(f"{log}: no instruction count from the plugin")
    total, marked, pairs = map(int, m.groups())
    return McuRun(values, marked / max(pairs, 1), total, pairs)
