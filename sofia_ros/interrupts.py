"""SIGINT and SIGTERM as a request to stop a run cleanly (close the bag, write summary.json).

``sofia`` installs :func:`install`; a run polls :func:`requested` where it can stop between
ticks (the lock-step runner's stop test, the clock node's watchdog, the wait for node
processes). Outside such a place - before anything is written - the signal raises
RunInterrupted at once; a second signal always does.
"""

from __future__ import annotations

import signal
import threading
from contextlib import contextmanager

from sofia_ros.errors import RunInterrupted

__all__ = ['install', 'restore', 'requested', 'graceful', 'raise_if_requested', 'reset', 'EXIT_CODES']

#: Shell convention: 128 + signal number.
EXIT_CODES = {signal.SIGINT: 130, signal.SIGTERM: 143}

_state = {'signum': None, 'graceful': 0}


def _handler(signum, frame):
    first = _state['signum'] is None
    _state['signum'] = signum
    if _state['graceful'] == 0 or not first:
        raise RunInterrupted(signum)


def install():
    """Route SIGINT and SIGTERM through the stop request; return the handlers they had (for restore)."""
    if threading.current_thread() is not threading.main_thread():
        return {}
    previous = {}
    for signum in (signal.SIGINT, signal.SIGTERM):
        previous[signum] = signal.signal(signum, _handler)
    return previous


def restore(previous):
    """Put back the handlers install() replaced."""
    for signum, handler in previous.items():
        if handler is not None:
            signal.signal(signum, handler)


def reset():
    """Forget an earlier request (a new run in the same process)."""
    _state['signum'] = None
    _state['graceful'] = 0


def requested():
    """The signal number that asked the run to stop, or None."""
    return _state['signum']


def raise_if_requested():
    """Raise RunInterrupted if a signal asked the run to stop."""
    if _state['signum'] is not None:
        raise RunInterrupted(_state['signum'])


@contextmanager
def graceful():
    """Inside: a first signal only sets the request; the code polls requested() and stops between ticks."""
    _state['graceful'] += 1
    try:
        yield
    finally:
        _state['graceful'] -= 1
