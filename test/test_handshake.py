"""The lock-step handshake's bookkeeping (nodes.sync): what a node keeps of its upstream's done reports."""

from sofia_ros.nodes.sync import UpstreamState, parse_stop, stop_text


def test_an_upstream_state_keeps_the_last_three_reports_of_a_long_run():
    state = UpstreamState()
    for tick in range(10_000):
        state.announce(tick, {'/truth/imu': tick})
    assert state.reports == {9997: {'/truth/imu': 9997}, 9998: {'/truth/imu': 9998}, 9999: {'/truth/imu': 9999}}
    assert state.latest_tick == 9999


def test_a_skipped_report_leaves_nothing_behind():
    state = UpstreamState()
    for tick in (0, 1, 2, 4, 7, 8):
        state.announce(tick, {})
    assert sorted(state.reports) == [7, 8]


def test_finished_and_failed_stick_once_reported():
    state = UpstreamState()
    state.announce(1, {}, failed='gyro_box: command outside the fine drive')
    state.announce(2, {}, finished=True)
    state.announce(3, {})
    assert (state.finished, state.failed) == (True, 'gyro_box: command outside the fine drive')


def test_a_stop_message_reads_back_with_a_semicolon_in_its_reason():
    assert parse_stop(stop_text(41, False, 'tascu stopped; the node is gone')) == (
        41, False, 'tascu stopped; the node is gone')
