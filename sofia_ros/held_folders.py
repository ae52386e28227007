"""Working folders that tell whether a process still works in them (a design's flights, compare's worker results).

A folder is made with a lock file locked (flock) by the process that made it; the workers it forks
inherit the lock, so it is held while that process or any of them runs, and released by the kernel
when the last of them ends, however it ends. A process killed outright (SIGKILL, out of memory)
cannot remove its folders: the next one to make such folders removes those whose lock nothing holds.
"""

from __future__ import annotations

import fcntl
import os
import shutil
import stat
import tempfile
import time
from pathlib import Path

__all__ = ['LOCK_FILE', 'UNLOCKED_FOLDER_AGE_S', 'held_folder', 'release_folder', 'remove_abandoned_folders']

#: The file in a held folder whose lock is held while a process works there.
LOCK_FILE = 'held.lock'
#: A folder without that file (made by an older version) is taken as abandoned after this long (s).
UNLOCKED_FOLDER_AGE_S = 86400.0


def held_folder(parent: Path, prefix: str, suffix: str = '') -> tuple[Path, int]:
    """A new folder ``parent/PREFIX<random>SUFFIX`` and the descriptor of its lock file, locked until
    release_folder. The file is locked before it takes its name: a lock file whose lock nothing holds
    is one whose process has ended."""
    folder = Path(tempfile.mkdtemp(prefix=prefix, suffix=suffix, dir=parent))
    locking = folder / f'{LOCK_FILE}.new'
    descriptor = None
    try:
        descriptor = os.open(locking, os.O_CREAT | os.O_WRONLY, 0o644)
        fcntl.flock(descriptor, fcntl.LOCK_EX)
        locking.rename(folder / LOCK_FILE)
    except BaseException:
        if descriptor is not None:
            os.close(descriptor)
        shutil.rmtree(folder, ignore_errors=True)
        raise
    return folder, descriptor


def release_folder(folder: Path, descriptor: int) -> None:
    """Remove a held_folder and drop its lock."""
    shutil.rmtree(folder, ignore_errors=True)
    os.close(descriptor)


def remove_abandoned_folders(parent: Path, pattern: str) -> None:
    """Remove the folders of ``parent`` named by the glob ``pattern`` whose lock nothing holds (and those
    without a lock file older than UNLOCKED_FOLDER_AGE_S). Only this user's folders are looked into, and
    only a regular lock file is opened: in a temporary directory others share, what another user put
    there (a pipe by that name would block the open) is left alone."""
    for folder in parent.glob(pattern):
        try:
            status = folder.lstat()
        except OSError:
            continue  # removed meanwhile
        if not stat.S_ISDIR(status.st_mode) or status.st_uid != os.geteuid():
            continue
        try:
            descriptor = os.open(folder / LOCK_FILE, os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK)
        except FileNotFoundError:
            if time.time() - status.st_mtime > UNLOCKED_FOLDER_AGE_S:
                shutil.rmtree(folder, ignore_errors=True)
            continue
        except OSError:
            continue  # not to be opened (a link, another's file)
        try:
            if not stat.S_ISREG(os.fstat(descriptor).st_mode):
                continue
            fcntl.flock(descriptor, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            continue  # in use
        else:
            shutil.rmtree(folder, ignore_errors=True)
        finally:
            os.close(descriptor)
