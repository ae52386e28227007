"""Claim a ROS domain for one run: a lock file per domain on this machine, held while the graph runs.

Two graphs in one ROS_DOMAIN_ID see each other's lock-step handshakes and deadlock or corrupt
each other's bags. A run claims its domain with ``fcntl.flock`` on
``/tmp/sofia_ros-domain-<id>.lock``: an exported ROS_DOMAIN_ID that another run holds is refused
at once; without one, a free domain is picked. The locks are in /tmp whatever a process's TMPDIR:
a DDS domain is the machine's, and a run with a temporary directory of its own (a batch job's)
must still see the other runs' claims.
"""

from __future__ import annotations

import fcntl
import os
import random
import tempfile
from contextlib import contextmanager
from pathlib import Path

from sofia_ros.errors import ConfigError, DomainBusyError

__all__ = ['DOMAIN_IDS', 'claim_ros_domain', 'claimed_ros_domain', 'domain_lock_directory', 'domain_lock_path',
           'release_ros_domain']

#: Domains usable on Linux with the default port mapping (0 is every tool's default, left alone).
DOMAIN_IDS = range(1, 102)


def domain_lock_directory():
    """Where every process on this machine keeps its domain locks: /tmp, or the temporary directory where /tmp
    cannot be written."""
    shared = Path('/tmp')
    return shared if os.access(shared, os.W_OK | os.X_OK) else Path(tempfile.gettempdir())


def domain_lock_path(domain_id):
    """The lock file of one domain on this machine."""
    return domain_lock_directory() / f'sofia_ros-domain-{domain_id}.lock'


def _try_lock(domain_id):
    """An open descriptor holding the domain's lock, or None when another run holds it."""
    try:
        descriptor = os.open(domain_lock_path(domain_id), os.O_RDWR | os.O_CREAT, 0o666)
    except PermissionError:
        return None  # another user's run created it
    try:
        fcntl.flock(descriptor, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        os.close(descriptor)
        return None
    return descriptor


class DomainClaim:
    """A held domain: its id, the lock's descriptor, and whether this run picked it."""

    def __init__(self, domain_id, descriptor, picked):
        self.domain_id = domain_id
        self.descriptor = descriptor
        self.picked = picked


def claim_ros_domain(environ=os.environ, rng=random):
    """Claim the exported ROS_DOMAIN_ID, or a free domain (then exported to ``environ``); DomainBusyError if taken."""
    environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    given = environ.get('ROS_DOMAIN_ID', '').strip()
    if given:
        try:
            domain_id = int(given)
        except ValueError as err:
            raise ConfigError(f'ROS_DOMAIN_ID must be an integer 0-232, got {given!r}') from err
        if not 0 <= domain_id <= 232:
            raise ConfigError(f'ROS_DOMAIN_ID must be an integer 0-232, got {domain_id}')
        descriptor = _try_lock(domain_id)
        if descriptor is None:
            raise DomainBusyError(f'ROS_DOMAIN_ID={domain_id} is in use by another sofia run on this machine '
                                  f'({domain_lock_path(domain_id)} is locked); export another ROS_DOMAIN_ID '
                                  'or unset it to get a free one')
        return DomainClaim(domain_id, descriptor, picked=False)
    candidates = list(DOMAIN_IDS)
    rng.shuffle(candidates)
    for domain_id in candidates:
        descriptor = _try_lock(domain_id)
        if descriptor is not None:
            environ['ROS_DOMAIN_ID'] = str(domain_id)
            return DomainClaim(domain_id, descriptor, picked=True)
    raise DomainBusyError(f'every ROS domain {DOMAIN_IDS.start}-{DOMAIN_IDS.stop - 1} is in use by sofia runs '
                          'on this machine; wait for one to finish')


def release_ros_domain(claim, environ=os.environ):
    """Release the lock; a picked domain is taken out of ``environ`` again."""
    if claim is None or claim.descriptor is None:
        return
    os.close(claim.descriptor)
    claim.descriptor = None
    if claim.picked and environ.get('ROS_DOMAIN_ID') == str(claim.domain_id):
        del environ['ROS_DOMAIN_ID']


@contextmanager
def claimed_ros_domain(environ=os.environ):
    """Hold a ROS domain for the body of the with-statement."""
    claim = claim_ros_domain(environ)
    try:
        yield claim
    finally:
        release_ros_domain(claim, environ)
