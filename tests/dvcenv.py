"""The environment of the tests' DVC and stage processes."""

import os
import sys
from pathlib import Path


def dvc_env(**extra: str) -> dict[str, str]:
    """This interpreter's ``python`` and ``dvc`` first on the path, DVC's analytics off, Python's
    string hashing seeded; ``extra`` added."""
    return dict(os.environ, PATH=str(Path(sys.executable).parent) + os.pathsep + os.environ.get("PATH", ""),
                DVC_NO_ANALYTICS="1", PYTHONHASHSEED="0", **extra)


def copy_model_code(root: Path, dest: Path) -> None:
    """Copy into ``dest`` the folder (or file) at the top of each model's own code in ``root``'s
    params.yaml that ``dest`` lacks: a user's models outside the library (the README's
    ``mymodels/``), which a copy of the project's code and settings must run too."""
    import shutil

    import yaml

    for model in yaml.safe_load((root / "params.yaml").read_text())["models"].values():
        top = Path(model["code"]).parts[0]
        if not (dest / top).exists():
            (shutil.copytree if (root / top).is_dir() else shutil.copy)(root / top, dest / top)
