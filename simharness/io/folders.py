"""Output folders: the one rule for writing into a folder, and the lock of a data set folder's writer.

Rule: a command writes into a new or empty folder; a non-empty one is refused with one line unless the
user passes `--force` (then files of the same name are replaced, others are left). Nothing is ever written
inside a data set folder (one holding a manifest), at any depth, `--force` or not: results beside or below
the shards would make the folder no longer a data set (readers that open it as one table would merge
them in). Outputs never go through a symbolic link inside an output folder, and a path that cannot be
written (under a regular file, in a read-only folder) is refused before any work.
"""

from __future__ import annotations

import contextlib
import fcntl
import os
import shutil
import sys
from collections.abc import Iterator
from pathlib import Path

from simharness.errors import UserError

LOCK = "_lock"  # `_`: readers of the folder as one table skip it
TMP_PREFIX = ".tmp-"  # temporary files and folders: `.tmp-{name}.{pid}.{random}`, renamed when complete
DATASET_MARKERS = ("_manifest.json", "manifest.json")
FIGURE_SUFFIXES = (".png", ".pdf", ".svg", ".jpg", ".jpeg")


def umask() -> int:
    """The process's umask (read by setting it and back: there is no getter)."""
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def dir_mode() -> int:
    """Mode of folders the project creates: 0755 under the usual umask 022 (mkdtemp alone gives 0700)."""
    return 0o777 & ~umask()


def file_mode() -> int:
    """Mode of files the project creates: 0644 under the usual umask 022 (mkstemp alone gives 0600)."""
    return 0o666 & ~umask()


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # alive, another user's
        return True
    return True


def clean_stale_temp(folder: Path, prefix: str = TMP_PREFIX) -> list[Path]:
    """Remove `{prefix}*.{pid}.{random}` files and folders in `folder` whose writer process is gone (a killed
    run's half-written outputs); a live writer's are left, links are removed, never followed. Returns them."""
    removed = []
    folder = Path(folder)
    if not folder.is_dir():
        return removed
    for p in folder.glob(f"{prefix}*"):
        parts = p.name.rsplit(".", 2)
        if len(parts) < 3 or not parts[1].isdigit() or _pid_alive(int(parts[1])):
            continue
        if p.is_dir() and not p.is_symlink():
            shutil.rmtree(p, ignore_errors=True)
        else:
            with contextlib.suppress(OSError):
                p.unlink()
        removed.append(p)
    return removed


def is_dataset_folder(path: Path) -> bool:
    """True if `path` holds a simharness data set manifest."""
    return any((Path(path) / m).is_file() for m in DATASET_MARKERS)


def dataset_ancestor(path: Path, include_self: bool = True) -> Path | None:
    """The nearest data set folder among `path` (if `include_self`) and the folders above it, as written and
    as resolved (a symbolic link into a data set counts), or None."""
    path = Path(path)
    for p in (path.absolute(), path.resolve()):
        for folder in ([p] if include_self else []) + list(p.parents):
            if is_dataset_folder(folder):
                return folder
    return None


def check_writable(path: Path, option: str = "--out", file: bool = False) -> None:
    """UserError (one line) unless `path` (a folder, or with `file` a file) could be created or written: its
    nearest existing ancestor must be a writable folder, and nothing between is a regular file."""
    path = Path(path).absolute()
    for p in [path, *path.parents]:
        if p.exists():
            if file and p == path and p.is_file():
                p = p.parent
            elif not p.is_dir():
                what = "names a file; expected a folder" if p == path else f"lies under {p}, which is a file"
                raise UserError(f"{path}: {option} {what}")
            if not os.access(p, os.W_OK | os.X_OK):
                raise UserError(f"{p}: not writable (permissions or a read-only file system); choose another "
                                f"{option}")
            return


def refuse_inside_dataset(path: Path, option: str = "--out", include_self: bool = True) -> None:
    """UserError if `path` is (or, with `include_self` False: lies strictly below) a data set folder."""
    found = dataset_ancestor(path, include_self)
    if found is not None:
        where = "is a data set folder" if Path(found) in (Path(path).absolute(), Path(path).resolve()) else \
            f"lies inside the data set folder {found}"
        raise UserError(f"{path}: {where}; writing there would spoil the data set: choose another {option}")


def refuse_symlinks(folder: Path, option: str = "--out") -> None:
    """UserError if `folder` holds a symbolic link: a write through it would land outside the folder."""
    folder = Path(folder)
    if folder.is_dir():
        links = sorted(p.name for p in folder.iterdir() if p.is_symlink())
        if links:
            raise UserError(f"{folder / links[0]}: is a symbolic link; {option} folders are written only directly, "
                            "never through a link: remove it or choose another folder")


def prepare_output(out: Path, force: bool = False, option: str = "--out") -> Path:
    """Check `out` against the rule above (before any work, so a refusal costs nothing); returns it.

    The folder is not created here: a command that then fails on its input leaves nothing behind.
    UserError (one line) if refused."""
    out = Path(out)
    check_writable(out, option)
    refuse_inside_dataset(out, option)
    if out.is_symlink():
        raise UserError(f"{out}: {option} is a symbolic link; name the folder itself")
    if out.is_dir() and any(out.iterdir()) and not force:
        raise UserError(f"{out}: exists and is not empty; choose another {option}, or pass --force to write into it")
    refuse_symlinks(out, option)
    clean_stale_temp(out)  # what a killed run into this folder left half-written
    return out


def prepare_figure(path: Path, option: str = "--figure") -> Path:
    """Check a figure file's path: a known image suffix, not a folder, writable, outside any data set."""
    path = Path(path)
    if path.is_dir():
        raise UserError(f"{path}: {option} names a folder; expected an image file such as frame.png")
    if path.suffix.lower() not in FIGURE_SUFFIXES:
        raise UserError(f"{path}: {option} has suffix {path.suffix or '(none)'!r}; expected one of "
                        f"{', '.join(FIGURE_SUFFIXES)}")
    if path.is_symlink():
        raise UserError(f"{path}: {option} is a symbolic link; name the file itself")
    check_writable(path, option, file=True)
    refuse_inside_dataset(path, option)
    return path


def make_folder(path: Path, option: str = "--out") -> Path:
    """mkdir -p with the project's folder mode; OSError (read-only, under a file) -> one UserError line."""
    try:
        Path(path).mkdir(parents=True, exist_ok=True, mode=dir_mode())
    except OSError as e:
        raise UserError(f"{path}: cannot create the {option} folder ({e.strerror or e})") from None
    return Path(path)


def open_append(folder: Path, name: str) -> int:
    """fd of `folder/name` for appending, created with the file mode; never through a symbolic link."""
    path = Path(folder) / name
    try:
        return os.open(path, os.O_WRONLY | os.O_APPEND | os.O_CREAT | os.O_NOFOLLOW, file_mode())
    except OSError as e:
        if path.is_symlink():
            raise UserError(f"{path}: is a symbolic link; refusing to write through it (remove it)") from None
        raise UserError(f"{path}: cannot write ({e.strerror or e})") from None


@contextlib.contextmanager
def writer_lock(folder: Path, what: str = "simharness generate") -> Iterator[None]:
    """Hold an exclusive `flock` on `folder/_lock` for the block: one writer at a time per data set folder.

    A second writer waits (saying so on stderr) and then resumes from what the first one left, so two
    runs into one folder end with every shard listed. The kernel drops the lock when a process dies,
    so a killed run never leaves the folder locked.
    """
    path = Path(folder) / LOCK
    try:
        fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_NOFOLLOW, file_mode())
    except OSError as e:
        raise UserError(f"{path}: cannot create the writer lock ({e.strerror or e}); a symbolic link or a "
                        "read-only folder?") from None
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            print(f"{what}: waiting for another writer of {folder} (lock {path}) to finish", file=sys.stderr)
            fcntl.flock(fd, fcntl.LOCK_EX)
        yield
    finally:
        os.close(fd)  # releases the lock
