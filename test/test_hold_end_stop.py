"""A hold that the Earth's turn drives into the fine drive's end stop ends there, with the reason.

The TASCU holds the star's attitude and the Earth's turn walks the fine drive meanwhile, about 3 deg of
LOS in 12 minutes. At the +-3 deg end stop the telescope rides with the cradle and the star is lost: a
plan's 1500 s hold then ended the alignment "timed out after 120 s waiting for the TASCU to report
locked" in the next element (measured on the default truth, seed 3). The hold now ends at the stop,
naming it (the same plan: "... drove the fine drive's LOS to its +-3 deg end stop after 718 s").
"""

from __future__ import annotations

from types import SimpleNamespace

import pytest

from sofia_ros import messages as m
from sofia_ros.errors import CalibrationAbort
from sofia_ros.mount import FINE_DRIVE_LIMIT_DEG
from sofia_ros.sim.sequence import SequenceCore
from sofia_ros.units import RAD_PER_DEG

TICK_S = 0.1


def _hold(los_deg_at, duration_s=10.0):
    """Run SequenceCore._hold_for on a stand-in whose LOS joint reads ``los_deg_at(t)``; its (start, end) s."""
    state = SimpleNamespace(stamp_ns=0, joints={})
    hold = SequenceCore._hold_for(state, duration_s)
    tick = 0
    while True:
        state.stamp_ns = m.seconds_to_ns(tick * TICK_S)
        state.joints = {'fd_el': 0.0, 'fd_xel': 0.0, 'fd_los': los_deg_at(tick * TICK_S) * RAD_PER_DEG}
        try:
            next(hold)
        except StopIteration as done:
            return done.value
        tick += 1


def test_a_hold_driven_into_the_end_stop_ends_there_naming_it():
    with pytest.raises(CalibrationAbort, match=r"drove the fine drive's LOS to its \+-3 deg end stop after 5 s"):
        _hold(lambda t: min(2.5 + 0.1 * t, FINE_DRIVE_LIMIT_DEG))


@pytest.mark.parametrize('los_deg_at', [
    lambda t: 2.5 + 0.01 * t,
    lambda t: FINE_DRIVE_LIMIT_DEG - 0.1 * t,
    lambda t: -FINE_DRIVE_LIMIT_DEG + 0.01 * t,
], ids=['walking-short-of-the-stop', 'started-at-the-stop-walking-away', 'started-at-the-other-stop-walking-away'])
def test_a_hold_short_of_the_end_stop_lasts_its_duration(los_deg_at):
    start_s, end_s = _hold(los_deg_at)
    assert (start_s, end_s) == (0.0, pytest.approx(10.0))
