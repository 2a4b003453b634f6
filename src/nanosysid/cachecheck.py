"""DVC's cache objects checked against their names.

An object of DVC's cache is named by the MD5 of its bytes. DVC checks a file output's object
before it checks it out, but not the objects a folder output lists: a damaged one (a disk error,
an edit through a link into the cache) is copied into the workspace, and ``dvc status`` still
says the pipeline is up to date, since it trusts the hashes it recorded. :func:`damaged` hashes
every object that ``dvc.lock`` names; :func:`remove` deletes the damaged ones, after which DVC
sees those outputs as not in the cache and runs their stages again. ``make repro`` does both
before it starts; ``python -m nanosysid.cachecheck`` checks without removing.
"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import dataclass
from pathlib import Path

import yaml

from nanosysid.guard import PIPELINE_FILES, file_md5

__all__ = ["Damaged", "damaged", "remove", "main"]

@dataclass(frozen=True)
class Damaged:
    """One object whose bytes do not hash to its name: the stage and output that name it."""

    stage: str
    output: str  # the workspace path (a file inside a folder output where it is one)
    path: Path  # the object in the cache
    found: str  # the MD5 its bytes have

    def __str__(self) -> str:
        return (f"{self.path}: the cache object of {self.output} (stage {self.stage}) hashes to {self.found}, "
                f"not to its name")


# the benchmark's pipelines' locks (the simulated world's, the real flights')
LOCKS = tuple((Path(f).parent / "dvc.lock").as_posix() for f in PIPELINE_FILES)


def _objects(lock: dict) -> list[tuple[str, str, str]]:
    """(stage, workspace path, md5) of every output ``dvc.lock`` records, a folder's as its
    listing's hash (``….dir``)."""
    return [(stage, out["path"], out["md5"]) for stage, rec in (lock.get("stages") or {}).items()
            if isinstance(rec, dict) for out in rec.get("outs") or [] if isinstance(out, dict) and out.get("md5")]


def damaged(root: Path = Path("."), cache: Path | None = None) -> list[Damaged]:
    """Every object of the repository's cache (``cache`` where given) that the benchmark's locks
    under ``root`` (:data:`LOCKS`) name, present, and not hashing to its name; a folder's listing
    and each file it lists. Objects not in the cache are DVC's to report (``not in cache``)."""
    root = Path(root)
    lock: dict = {"stages": {}}
    for f in LOCKS:
        try:
            lock["stages"].update((yaml.safe_load((root / f).read_text()) or {}).get("stages") or {})
        except (FileNotFoundError, yaml.YAMLError, AttributeError):  # no lock, or one DVC refuses with its message
            continue
    if not lock["stages"]:
        return []
    if cache is None:
        from dvc.repo import Repo

        with Repo(str(root)) as repo:  # where the repository's configuration puts its cache
            cache = Path(repo.cache.local.path)
    found: list[Damaged] = []

    def check(stage: str, output: str, md5: str) -> Path | None:
        path = cache / md5[:2] / md5[2:]
        if not path.is_file():
            return None
        actual = file_md5(path)
        if actual != md5.removesuffix(".dir"):
            found.append(Damaged(stage, output, path, actual))
            return None
        return path

    for stage, output, md5 in _objects(lock):
        listing = check(stage, output, md5)
        if listing is None or not md5.endswith(".dir"):
            continue
        for entry in json.loads(listing.read_text()):
            check(stage, f"{output}/{entry['relpath']}", entry["md5"])
    return found


def remove(objects: list[Damaged]) -> None:
    """Delete each damaged object from the cache (DVC's own answer to a corrupted object), so that
    the stage that wrote it runs again instead of checking it out."""
    for d in objects:
        d.path.unlink(missing_ok=True)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description="Check every DVC cache object dvc.lock names against its name.")
    p.add_argument("--remove", action="store_true", help="delete the damaged objects (their stages run again)")
    a = p.parse_args(argv)
    from dvc.exceptions import DvcException

    try:
        bad = damaged()
    except DvcException as e:  # not a DVC repository, a configuration DVC refuses: its own words
        print(f"error: {e}", file=sys.stderr)
        return 2
    for d in bad:
        print(d, file=sys.stderr)
    if bad and a.remove:
        remove(bad)
        print(f"{len(bad)} damaged objects removed; `make repro` runs their stages again", file=sys.stderr)
    elif not bad:
        print("every cache object dvc.lock names hashes to its name")
    return 1 if bad and not a.remove else 0


if __name__ == "__main__":
    raise SystemExit(main())
