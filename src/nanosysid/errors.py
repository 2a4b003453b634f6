"""The errors a user's mistake or a missing tool raise: each ends a stage with one message
(naming the file, the key or the field and the problem) and exit code 2, never a traceback."""

from __future__ import annotations

__all__ = ["UserError", "DataError", "ConfigError", "PredictionError", "ExportError", "NotExportable", "ToolchainError", "JobError"]


class UserError(ValueError):
    """Base of the errors a stage reports as one message."""


class DataError(UserError):
    """A data file that does not meet its schema; the message names file, field and row."""


class ConfigError(UserError):
    """A config file or an override that cannot be applied."""


class PredictionError(UserError):
    """A predictor returned something that cannot be scored: a wrong shape, a non-finite value,
    a quaternion far from unit norm."""


class ExportError(UserError):
    """A model cannot be exported, or its export does not compute what PyTorch computes."""


class NotExportable(ExportError):
    """A model whose step needs what the exported step is not given (the rotor speeds' history):
    the export stage records why, and the microcontroller stage has nothing to run."""


class ToolchainError(UserError):
    """A tool the microcontroller stages need is missing."""


class JobError(UserError):
    """A task the cluster ran failed, or the cluster ended it (time, memory); the message names
    the job and where its log is."""
