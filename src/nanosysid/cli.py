"""Shared entry-point plumbing for the stage scripts in ``stages/``.

Every stage runs as ``python -m stages.<name> [NAME] [key=value ...]``: an optional
positional name (the ``foreach`` item, e.g. the model) and Hydra-style overrides applied on
top of ``params.yaml``. Data errors end the stage with one message and exit code 2.
"""

from __future__ import annotations

import argparse
import logging
import sys
from typing import Callable, Sequence

from omegaconf import DictConfig

from nanosysid.config import ConfigError, load_params
from nanosysid.dataio import DataError
from nanosysid.export import ExportError, ToolchainError

__all__ = ["run_stage"]

log = logging.getLogger("nanosysid")


def run_stage(
    main: Callable[..., None],
    *,
    description: str,
    name_arg: str | None = None,
    argv: Sequence[str] | None = None,
) -> int:
    """Parse the command line, load the config and call ``main(cfg)`` or ``main(cfg, name)``."""
    parser = argparse.ArgumentParser(description=description)
    if name_arg:
        parser.add_argument(name_arg)
    parser.add_argument("overrides", nargs="*", help="Hydra-style overrides, e.g. eval.horizon=20")
    parser.add_argument("--params", default=None, help="params file (default: params.yaml)")
    args = parser.parse_intermixed_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    try:
        kw = {"path": args.params} if args.params else {}
        cfg: DictConfig = load_params(args.overrides, **kw)
        if name_arg:
            main(cfg, getattr(args, name_arg))
        else:
            main(cfg)
    except (DataError, ConfigError, ExportError, ToolchainError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    return 0
