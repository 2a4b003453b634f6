"""The pipeline's stages: one script each, run as ``python -m stages.<name>``."""

from nanosysid import numerics

# before torch and numpy are loaded: the same bytes on every x86 machine (of the stage's level)
numerics.pin(numerics.stage_level())
