"""The environment of the tests' DVC and stage processes."""

import os
import sys
from pathlib import Path


def dvc_env(**extra: str) -> dict[str, str]:
    """This interpreter's ``python`` and ``dvc`` first on the path, DVC's analytics off, Python's
    string hashing seeded; ``extra`` added."""
    return dict(os.environ, PATH=str(Path(sys.executable).parent) + os.pathsep + os.environ.get("PATH", ""),
                DVC_NO_ANALYTICS="1", PYTHONHASHSEED="0", **extra)
