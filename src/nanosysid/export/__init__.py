"""Models on the microcontroller: what a step costs, ONNX, generated C, the emulated STM32."""

__all__ = ["ExportError", "ToolchainError"]


class ExportError(RuntimeError):
    """A model cannot be exported, or its export does not compute what PyTorch computes."""


class ToolchainError(RuntimeError):
    """A tool the microcontroller stages need is missing."""
