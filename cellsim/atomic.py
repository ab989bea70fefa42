"""Writing files safely: atomically (readers see the old content or the new,
never a part), and into folders no other cellsim process is writing.

Every file cellsim writes for the user to keep (resolved scenarios, traces,
results, reports) goes through :func:`write_text`; a run folder and a campaign
folder are held with :func:`folder_lock` while they are written.
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import os
import stat
import tempfile
from pathlib import Path

LOCK = ".cellsim.lock"
"""The lock file of a folder cellsim writes (a run's, a campaign's)."""


class FolderBusy(Exception):
    """Another process holds the folder's lock."""


@contextlib.contextmanager
def folder_lock(folder: str | os.PathLike):
    """Hold an exclusive lock on ``folder`` (which must exist) while the block runs.

    The lock is an ``flock`` on ``folder/.cellsim.lock``: a second process asking
    for it is refused at once (:class:`FolderBusy`), and it goes with its holder
    however that ends, SIGKILL included.
    """
    fd = os.open(Path(folder) / LOCK, os.O_RDWR | os.O_CREAT, 0o644)
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            raise FolderBusy(str(folder)) from None
        yield
    finally:
        os.close(fd)  # closing the descriptor releases the lock


class OverwritesInput(ValueError):
    """An output path names a file the same command reads (a run's black box, its scenario)."""


def refuse_inputs(path: str | os.PathLike, inputs, what: str) -> None:
    """Refuse (:class:`OverwritesInput`) to write ``what`` (the trace, the MCAP file) at ``path`` when it is, or
    links to, one of ``inputs`` (the files it is made from: writing it would destroy them)."""
    target = os.path.realpath(path)
    for item in inputs:
        if item is not None and os.path.exists(item) and os.path.realpath(item) == target:
            raise OverwritesInput(f"will not write {what} over {os.fspath(path)}: it is {os.fspath(item)}, which "
                                  f"{what} is made from; name another file")


def write_text(path: str | os.PathLike, text: str, *, make_folder: bool = False) -> None:
    """Write ``text`` to ``path`` atomically (:func:`replacing`)."""
    with replacing(path, "w", make_folder=make_folder) as f:
        f.write(text)


@contextlib.contextmanager
def replacing(path: str | os.PathLike, mode: str = "w", *, make_folder: bool = False):
    """A file (``mode`` "w" for text, "wb" for bytes) whose content replaces ``path`` when the block ends.

    The content goes to a temporary file in the same folder, which then replaces the file
    (:func:`os.replace`): readers see the old content or the new, never a part; on any error, Ctrl-C
    included, the temporary file is removed and ``path`` is as it was. A symbolic link is written
    through (the file it names is replaced, the link stays); a path that is a device or a pipe
    (``/dev/stdout``, a FIFO) is written into directly, as no file can replace it. A ``path`` that is a
    folder is refused (``IsADirectoryError``) before anything is written; its folder must exist unless
    ``make_folder`` (a file in its place: ``NotADirectoryError``). Every error names ``path``, never the
    temporary file.
    """
    path = os.fspath(path)
    if os.path.isdir(path):
        raise IsADirectoryError(errno.EISDIR, "is a folder; name a file to write", path)
    if os.path.exists(path) and (not stat.S_ISREG(os.stat(path).st_mode) or path.startswith("/dev/")):
        # a device or a pipe, links followed; or /dev/stdout sent to a file (>> appends to it: written into)
        with open(path, mode, **({} if "b" in mode else {"encoding": "utf-8"})) as f:
            yield f
        return
    real = os.path.realpath(path)
    folder = os.path.dirname(real)
    if make_folder:
        os.makedirs(folder, exist_ok=True)
    elif os.path.exists(folder) and not os.path.isdir(folder):
        raise NotADirectoryError(errno.ENOTDIR, "is a file, not a folder to write into", os.path.dirname(path) or folder)
    elif not os.path.isdir(folder):
        raise FileNotFoundError(errno.ENOENT, "no such folder to write into", os.path.dirname(path) or folder)
    try:
        fd, tmp = tempfile.mkstemp(dir=folder, prefix=f".{os.path.basename(real)}.", suffix=".tmp")
    except OSError as e:
        raise OSError(e.errno, e.strerror, path) from None
    try:
        with os.fdopen(fd, mode, **({} if "b" in mode else {"encoding": "utf-8"})) as f:
            yield f
            f.flush()
            os.fsync(f.fileno())
        mode_bits = os.stat(real).st_mode & 0o777 if os.path.exists(real) else 0o644
        os.chmod(tmp, mode_bits)
        os.replace(tmp, real)
    except BaseException as e:
        try:
            os.unlink(tmp)
        except FileNotFoundError:
            pass
        if isinstance(e, OSError) and e.filename == tmp:
            raise OSError(e.errno, e.strerror, path) from None
        raise
