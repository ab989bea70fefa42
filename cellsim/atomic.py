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


def write_text(path: str | os.PathLike, text: str, *, make_folder: bool = False) -> None:
    """Write ``text`` to ``path`` atomically.

    The text goes to a temporary file in the same folder, which then replaces
    ``path`` (:func:`os.replace`); on any error, Ctrl-C included, the temporary
    file is removed. A ``path`` that is a folder is refused (``IsADirectoryError``)
    before anything is written; its folder must exist unless ``make_folder``.
    """
    path = os.fspath(path)
    if os.path.isdir(path):
        raise IsADirectoryError(errno.EISDIR, "is a folder; name a file to write", path)
    folder = os.path.dirname(os.path.abspath(path))
    if make_folder:
        os.makedirs(folder, exist_ok=True)
    elif not os.path.isdir(folder):
        raise FileNotFoundError(errno.ENOENT, "no such folder to write into", folder)
    fd, tmp = tempfile.mkstemp(dir=folder, prefix=f".{os.path.basename(path)}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as f:
            f.write(text)
            f.flush()
            os.fsync(f.fileno())
        mode = os.stat(path).st_mode & 0o777 if os.path.exists(path) else 0o644
        os.chmod(tmp, mode)
        os.replace(tmp, path)
    except BaseException:
        try:
            os.unlink(tmp)
        except FileNotFoundError:
            pass
        raise
