"""Progress of long offline commands (compare, search, design) on stderr: the phase and a count where there is one.

Nothing goes to stdout, so printed reports and --json stay the same. Lines are written only once the command
has run past ``quiet_for_s`` (a quick compare prints nothing) and at most every ``interval_s`` seconds;
``Progress.silent()`` writes nothing (--quiet, the library API, the tests).
"""

from __future__ import annotations

import sys
import time
from typing import TextIO

__all__ = ['Progress']


class Progress:
    """Reports phases (``phase('reading the bag')``) and counts (``count('fitting candidates', 3, 14)``)."""

    def __init__(self, stream: TextIO | None = sys.stderr, *, prefix: str = 'sofia', quiet_for_s: float = 3.0,
                 interval_s: float = 2.0) -> None:
        self.stream = stream
        self.prefix = prefix
        self.quiet_for_s = quiet_for_s
        self.interval_s = interval_s
        self.started_s = time.monotonic()
        self.last_line_s = -float('inf')

    @classmethod
    def silent(cls) -> Progress:
        """A Progress that writes nothing."""
        return cls(None)

    def phase(self, text: str) -> None:
        """A new phase: written once the command has run past quiet_for_s."""
        self._offer(text, force=True)

    def count(self, text: str, done: int, total: int) -> None:
        """``done`` of ``total`` items of the current phase, e.g. 'fitting candidates 3/14'."""
        self._offer(f'{text} {done}/{total}', force=done == total)

    def _offer(self, line: str, *, force: bool) -> None:
        if self.stream is None:
            return
        now_s = time.monotonic()
        elapsed_s = now_s - self.started_s
        if elapsed_s < self.quiet_for_s or (not force and now_s - self.last_line_s < self.interval_s):
            return
        self.last_line_s = now_s
        self.stream.write(f'{self.prefix}: {line} ({elapsed_s:.0f} s)\n')
        self.stream.flush()
