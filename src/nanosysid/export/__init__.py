"""Models on the microcontroller: what a step costs, ONNX, generated C, the emulated STM32."""

CLOCK_HZ = 168e6  # STM32F405
# QEMU has no timing model of the Cortex-M4 (pipeline, flash wait states): cycles are not counted,
# they lie between one an instruction and this many: 14 for VDIV.F32 and VSQRT.F32, the longest
# (Cortex-M4 TRM, table 7-1 of the FPU's instruction timing), plus the 5 flash wait states of the
# STM32F405 at 168 MHz (RM0090, table 10) where the ART accelerator's cache misses
MAX_CYCLES_PER_INSTRUCTION = 19
