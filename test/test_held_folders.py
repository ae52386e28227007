"""held_folders: working folders whose lock says whether a process still works in them."""

from __future__ import annotations

import os
import subprocess
import sys
import time

from sofia_ros.held_folders import LOCK_FILE, UNLOCKED_FOLDER_AGE_S, held_folder, release_folder, \
    remove_abandoned_folders


def test_a_folder_nothing_holds_is_removed_and_one_in_use_is_kept(tmp_path):
    """Its process killed (the lock dropped): removed. Held here, or by another process (a worker, another command in
    another PID namespace): kept. An older version's (no lock file): kept for a day. Other names: not looked at."""
    killed, killed_lock = held_folder(tmp_path, 'job-')
    os.close(killed_lock)
    held, held_lock = held_folder(tmp_path, 'job-')
    elsewhere, elsewhere_lock = held_folder(tmp_path, 'job-')
    os.close(elsewhere_lock)
    old, older, other = tmp_path / 'job-old', tmp_path / 'job-older', tmp_path / 'notes'
    for folder in (old, older, other):
        folder.mkdir()
    a_day_ago_s = time.time() - UNLOCKED_FOLDER_AGE_S - 60.0
    os.utime(older, (a_day_ago_s, a_day_ago_s))
    holder = subprocess.Popen([sys.executable, '-c', 'import fcntl, os, sys, time\n'
                               f'd = os.open({str(elsewhere / LOCK_FILE)!r}, os.O_RDONLY)\n'
                               'fcntl.flock(d, fcntl.LOCK_EX); print("held", flush=True); time.sleep(60)'],
                              stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline() == 'held\n'
        remove_abandoned_folders(tmp_path, 'job-*')
    finally:
        holder.kill()
        holder.wait()
    assert sorted(path.name for path in tmp_path.iterdir()) == sorted([held.name, elsewhere.name, old.name, 'notes'])
    release_folder(held, held_lock)
    assert not held.exists()


def test_the_lock_is_held_by_the_workers_forked_while_it_is(tmp_path):
    folder, lock = held_folder(tmp_path, 'job-')
    go_on, release = os.pipe()
    worker = os.fork()
    if worker == 0:
        try:
            os.read(go_on, 1)  # until the parent has looked
        finally:
            os._exit(0)
    os.close(lock)  # this process done with it; its worker still runs
    remove_abandoned_folders(tmp_path, 'job-*')
    assert folder.exists()
    os.write(release, b'x')
    os.waitpid(worker, 0)
    remove_abandoned_folders(tmp_path, 'job-*')
    assert not folder.exists()


def test_what_another_user_could_put_in_a_shared_temporary_directory_is_left_alone(tmp_path):
    """A pipe by the lock file's name would block an open; a link would lead elsewhere: neither is followed."""
    piped = tmp_path / 'job-piped'
    piped.mkdir()
    os.mkfifo(piped / LOCK_FILE)
    target = tmp_path / 'elsewhere'
    target.mkdir()
    (tmp_path / 'job-linked').symlink_to(target)
    remove_abandoned_folders(tmp_path, 'job-*')
    assert piped.exists() and target.exists() and (tmp_path / 'job-linked').is_symlink()
