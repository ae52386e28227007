"""The one retry the DDS graph tests allow: a graph whose eleven node processes did not all come up.

The start-up failures these retries were written for had two causes, both fixed: the recorder
recorded every /parameter_events message in the domain and crashed on a wall-time stamp (the
nodes that wait for it as a subscriber then never connected), and a node process could deadlock
in Fast DDS 3.2 destroying the writers of the temporary node that read its parameters. After the
fixes, 36 short `--processes` runs three at a time all started. The retry stays as a guard for
eleven processes discovering each other on a loaded machine: only a run whose clock reports nodes
that "did not connect within" is retried, any other failure fails at once.

Two more start-up faults remain below this code, in the DDS layer of the PyPI wheels: three
`--processes` graphs at once on two cores with a busy loop beside them (2026-11-28) stalled on
their first tick in 3 of 89 starts (a node connected, then fell silent: py-spy shows it idle in
the EventsExecutor's wait with none of its DDS events arriving, not even /sim/stop; CI met it in
two runs in a row), and one node process died of SIGSEGV in its parameter reader in 41. Neither
depends on what a test asserts, and a new start does not meet them again: they are retried too.
`sofia run --processes` itself starts a graph stalled on its first tick once more (campaigns.recording);
what reaches a test is two such stalls in a row, or the SIGSEGV.
"""

import pytest

__all__ = ['STARTUP_RERUNS']

STARTUP_RERUNS = pytest.mark.flaky(reruns=2, only_rerun=['did not connect within', 'stopped reporting at tick 1 ',
                                                         'while the graph was starting'])
