"""The one retry the DDS graph tests allow: a graph whose eleven node processes did not all come up.

The flake these retries were written for had a cause, since fixed: the recorder recorded every
/parameter_events message in the domain and crashed on a wall-time stamp from the executables'
parameter readers (so the nodes that wait for it as a subscriber never connected). One start-up
failure stays unexplained: on a loaded machine, a node process once logged nothing for two
minutes. The clock then ends the run with "... did not connect within 120 s"; only such a run is
retried, any other failure fails at once.
"""

import pytest

__all__ = ['STARTUP_RERUNS']

STARTUP_RERUNS = pytest.mark.flaky(reruns=2, only_rerun=['did not connect within'])
