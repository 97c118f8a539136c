"""The recordings ``hilident batch`` is given: files, folders (searched recursively) and globs; their hashes."""

from __future__ import annotations

import glob
import hashlib
from pathlib import Path

from hilident.errors import UsageError

#: File endings of the recordings ``hilident identify`` reads (hilident HDF5, CSV, MATLAB).
RECORDING_SUFFIXES = (".h5", ".hdf5", ".csv", ".mat")

_GLOB_CHARS = "*?["
_HASH_BLOCK_BYTES = 1 << 20


def _is_recording(path: Path) -> bool:
    return path.is_file() and path.suffix.lower() in RECORDING_SUFFIXES


def _expand_one(given: str) -> list[Path]:
    """The recordings one argument names: a file as given, a folder's recordings at any depth, a glob's matches."""
    path = Path(given)
    if path.is_dir():
        return [p for p in path.rglob("*") if _is_recording(p)]
    if path.is_file():
        return [path]
    if any(c in given for c in _GLOB_CHARS):
        found: list[Path] = []
        for match in map(Path, glob.glob(given, recursive=True)):
            found += (
                [p for p in match.rglob("*") if _is_recording(p)]
                if match.is_dir()
                else ([match] if _is_recording(match) else [])
            )
        return found
    return []


def expand_inputs(inputs: list[str]) -> list[Path]:
    """The recordings ``inputs`` name, sorted, each once.

    Parameters
    ----------
    inputs : list of str
        Files (taken whatever their ending: ``identify`` says what it cannot
        read), folders (their ``.h5``, ``.hdf5``, ``.csv`` and ``.mat`` files
        at any depth) and globs (``runs/*/axis*.h5``; ``**`` for any depth).

    Raises
    ------
    UsageError
        An input that names no recording (the message names it).
    """
    if not inputs:
        raise UsageError("hilident batch: give at least one recording, folder or glob")
    found: dict[Path, None] = {}
    for given in inputs:
        paths = _expand_one(given)
        if not paths:
            what = (
                "a folder holding no recording (.h5, .hdf5, .csv, .mat)"
                if Path(given).is_dir()
                else "no file, folder or glob matching a recording"
            )
            raise UsageError(f"batch input {given}: {what}")
        for p in paths:
            found[p.resolve()] = None
    return sorted(found)


def content_sha256(path: str | Path) -> str:
    """SHA-256 of the file's bytes, hex; the key under which its row is kept (a renamed file is not redone)."""
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        while block := f.read(_HASH_BLOCK_BYTES):
            digest.update(block)
    return digest.hexdigest()
