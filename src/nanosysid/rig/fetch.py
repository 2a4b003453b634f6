"""The rig's files, from a local folder or the upstream repository at a pinned commit, each one
checked against the SHA-256 manifest the project commits.

The manifest has one line a file: ``<sha256>  <path here>  <path upstream>``. A local folder
must hold exactly the manifest's files under their paths here (another campaign's flights beside
them are refused: they are not the benchmark's); without one, every file is read through DVC from
the upstream git repository at the pinned commit (:class:`dvc.api.DVCFileSystem`, as ``dvc import``
reads it: one clone, plain git blobs at that commit). Either way the files are written to the
output folder only when every one arrived and matched.
"""

from __future__ import annotations

import hashlib
import logging
import os
import shutil
import subprocess
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

from tqdm.auto import tqdm

from nanosysid.dataio import atomic_dir
from nanosysid.errors import DataError

__all__ = ["Entry", "read_manifest", "sha256", "local_source", "fetch"]

log = logging.getLogger(__name__)

HEX = set("0123456789abcdef")


@dataclass(frozen=True)
class Entry:
    """One file of the manifest: its SHA-256, its path here and its path upstream."""

    sha256: str
    path: str
    upstream: str


def read_manifest(path: str | Path) -> list[Entry]:
    """The manifest's entries, in its order.

    Raises:
        DataError: a missing file, a line without three fields, a hash that is not 64 hex
            digits, a path that leaves its folder, or a path twice; naming the line.
    """
    path = Path(path)
    if not path.is_file():
        raise DataError(f"{path}: no such manifest (rig.manifest)")
    entries: list[Entry] = []
    seen: set[str] = set()
    for i, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
        if not line.strip() or line.lstrip().startswith("#"):
            continue
        fields = line.split()
        if len(fields) != 3:
            raise DataError(f"{path}, line {i}: {len(fields)} fields; a line is '<sha256>  <path here>  <path upstream>'")
        digest, here, there = fields
        if len(digest) != 64 or not set(digest) <= HEX:
            raise DataError(f"{path}, line {i}: {digest!r} is not a SHA-256 (64 lower-case hex digits)")
        if Path(here).is_absolute() or ".." in Path(here).parts:
            raise DataError(f"{path}, line {i}: the path {here!r} leaves the data folder")
        if here in seen:
            raise DataError(f"{path}, line {i}: {here} is listed twice")
        seen.add(here)
        entries.append(Entry(digest, here, there))
    if not entries:
        raise DataError(f"{path}: the manifest lists no file")
    return entries


def sha256(path: Path) -> str:
    """The SHA-256 of a file, hex."""
    with open(path, "rb") as f:
        return hashlib.file_digest(f, "sha256").hexdigest()


def local_source(local: str | Path | None, entries: Sequence[Entry]) -> Path | None:
    """The local folder when one is set and exists, else None (the files come from upstream).

    Raises:
        DataError: the folder lacks a file of the manifest, or holds flights the manifest does
            not list (another campaign, or a folder of a researcher's own flights).
    """
    if local is None or not Path(local).is_dir():
        return None
    folder = Path(local)
    missing = [e.path for e in entries if not (folder / e.path).is_file()]
    if missing:
        raise DataError(f"{folder / missing[0]}: missing ({len(missing)} of the manifest's {len(entries)} files are "
                        f"not in rig.local = {folder}); copy the campaign's files there as the manifest names them, or "
                        "set rig.local=null to download them")
    listed = {e.path for e in entries}
    others = sorted(str(p.relative_to(folder)) for p in folder.rglob("*")
                    if p.suffix in (".parquet", ".csv") and str(p.relative_to(folder)) not in listed)
    if others:
        raise DataError(f"{folder / others[0]}: not in the manifest ({len(others)} such flight file(s) in rig.local); "
                        "the folder must hold the pinned campaign alone: bring your own flights in as a data "
                        "source of their own (conf/data/csv.yaml)")
    return folder


def _upstream(repository: str, commit: str, local: str | Path | None = None):
    """DVC's file system over the upstream git repository at ``commit`` (one clone); ``local``, the
    rig.local that was not a folder of the files, named where the repository cannot be reached.

    Raises:
        DataError: the repository cannot be reached or has no such commit.
    """
    from dvc.api import DVCFileSystem
    from dvc.exceptions import DvcException

    try:
        fs = DVCFileSystem(repository, rev=commit)
        fs.repo  # noqa: B018 (the clone happens here; a lazy one would read a failure as a missing file)
        return fs
    except (DvcException, OSError, ValueError) as e:
        cause = f"{type(e).__name__}: {e}" + (f"; {e.__cause__}" if e.__cause__ else "")
        if local is not None:
            what = "a file, not a folder" if Path(local).is_file() else "no such folder"
            raise DataError(f"rig.local = {local} is {what} ({Path(local).resolve()}), so the files were fetched from "
                            f"{repository} at {commit}, which cannot be reached ({cause}); set rig.local to the folder "
                            "holding the campaign's files") from None
        raise DataError(f"{repository} at {commit}: cannot be fetched through DVC ({cause}); without a network, set "
                        "rig.local to a folder holding the campaign's files") from None


def _copy_upstream(fs, e: Entry, dest: Path, where: str) -> None:
    if not fs.exists(e.upstream):
        raise DataError(f"{where}: not in the upstream repository at that commit; check rig.upstream and the manifest")
    with fs.open(e.upstream, "rb") as src, open(dest, "wb") as out:
        shutil.copyfileobj(src, out)


def fetch(manifest: str | Path, out_dir: str | Path, *, local: str | Path | None, repository: str,
          commit: str) -> dict:
    """Copy (from ``local``) or fetch through DVC (from ``repository`` at ``commit``) every file of
    the manifest into ``out_dir`` and check its SHA-256.

    Returns:
        ``{"source": "local" | "upstream", "files": {path: sha256}}``.

    Raises:
        DataError: a file missing, unreachable or whose SHA-256 differs from the manifest's;
            nothing is written then.
    """
    entries = read_manifest(manifest)
    folder = local_source(local, entries)
    fs = _upstream(repository, commit, local) if folder is None else None
    with atomic_dir(out_dir, inputs=[folder] if folder else ()) as tmp:
        for e in tqdm(entries, desc="fetch", unit="file", disable=None):
            dest = tmp / e.path
            dest.parent.mkdir(parents=True, exist_ok=True)
            if folder is not None:
                where = str(folder / e.path)
                shutil.copyfile(folder / e.path, dest)
            else:
                where = f"{repository}@{commit[:12]}:{e.upstream}"
                _copy_upstream(fs, e, dest, where)
            found = sha256(dest)
            if found != e.sha256:
                raise DataError(f"{where}: SHA-256 {found}, but the manifest {manifest} says {e.sha256}: not the "
                                "pinned campaign's file (changed or damaged); nothing was written")
    source = "local" if folder is not None else "upstream"
    log.info("fetch: %d files from %s, every SHA-256 as in %s", len(entries), folder or repository, manifest)
    return {"source": source, "files": {e.path: e.sha256 for e in entries}}


def available(manifest: str | Path, raw_dir: str | Path, *, local: str | Path | None, repository: str,
              commit: str, timeout: float = 20.0) -> tuple[bool, str]:
    """Whether the rig's files can be had here, and from where (or why not): already fetched,
    in the local folder, or upstream (``git ls-remote``, one round trip)."""
    try:
        entries = read_manifest(manifest)
    except DataError as e:
        return False, str(e)
    if all((Path(raw_dir) / e.path).is_file() for e in entries):
        return True, f"fetched in {raw_dir}"
    if local is not None and Path(local).is_dir():
        return True, f"the local folder {local}"
    try:
        r = subprocess.run(["git", "ls-remote", "--exit-code", str(repository), "HEAD"], capture_output=True, text=True,
                           timeout=timeout, env=dict(os.environ, GIT_TERMINAL_PROMPT="0"))
        if r.returncode == 0:
            return True, f"upstream ({repository} at {commit[:12]})"
        why = (r.stderr.strip().splitlines() or [f"git exit {r.returncode}"])[-1]
    except (OSError, subprocess.TimeoutExpired) as e:
        why = str(e)
    return False, f"no folder at rig.local = {local} and {repository} cannot be reached ({why})"
