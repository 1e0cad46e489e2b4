"""Output folders: the one rule for writing into a folder, and the lock of a data set folder's writer.

Rule: a command writes into a new or empty folder; a non-empty one is refused with one line unless the
user passes `--force` (then files of the same name are replaced, others are left). A data set folder
(one holding a manifest) is never an output folder of another command, `--force` or not: results
beside the shards would make the folder no longer a data set.
"""

from __future__ import annotations

import contextlib
import fcntl
import os
import sys
from collections.abc import Iterator
from pathlib import Path

from simharness.errors import UserError

LOCK = "_lock"  # `_`: readers of the folder as one table skip it
DATASET_MARKERS = ("_manifest.json", "manifest.json")


def is_dataset_folder(path: Path) -> bool:
    """True if `path` holds a simharness data set manifest."""
    return any((Path(path) / m).is_file() for m in DATASET_MARKERS)


def prepare_output(out: Path, force: bool = False, option: str = "--out") -> Path:
    """Check `out` against the rule above (before any work, so a refusal costs nothing); returns it.

    The folder is not created here: a command that then fails on its input leaves nothing behind.
    UserError (one line) if refused."""
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise UserError(f"{out}: {option} names a file; expected a folder")
    if out.is_dir() and is_dataset_folder(out):
        raise UserError(f"{out}: is a data set folder; writing results into it would spoil the data set: choose "
                        f"another {option}")
    if out.is_dir() and any(out.iterdir()) and not force:
        raise UserError(f"{out}: exists and is not empty; choose another {option}, or pass --force to write into it")
    return out


@contextlib.contextmanager
def writer_lock(folder: Path, what: str = "simharness generate") -> Iterator[None]:
    """Hold an exclusive `flock` on `folder/_lock` for the block: one writer at a time per data set folder.

    A second writer waits (saying so on stderr) and then resumes from what the first one left, so two
    runs into one folder end with every shard listed. The kernel drops the lock when a process dies,
    so a killed run never leaves the folder locked.
    """
    path = Path(folder) / LOCK
    fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            print(f"{what}: waiting for another writer of {folder} (lock {path}) to finish", file=sys.stderr)
            fcntl.flock(fd, fcntl.LOCK_EX)
        yield
    finally:
        os.close(fd)  # releases the lock
