"""The alignment campaign end to end through the lock-step runner (reduced size, same code paths)."""

import json

import numpy as np
import pytest
import yaml
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from rosbags.highlevel import AnyReader

from sofia_ros.analysis.alignment_bag import refit_alignments
from sofia_ros.bag import BagReader
from sofia_ros.campaigns.alignment import graph_config, run_alignment
from sofia_ros.config import load_effect_config
from sofia_ros.sim.calibration import AlignmentPlan
from sofia_ros.sim.graph import build_cores, graph_topics
from sofia_ros.topics import DEFAULT_TICK_NS

NOMINAL = load_effect_config('config/truth/nominal.yaml')
# Reduced campaign: 4 repetitions (the residual drift fit needs >= 4), 1 verification pair, 30 s drift track.
PLAN = AlignmentPlan(repetitions=4, verification_repetitions=1, drift_track_s=30.0)


@pytest.fixture(scope='module')
def nominal_run(tmp_path_factory):
    bag = tmp_path_factory.mktemp('runs') / 'nominal'
    return run_alignment(NOMINAL, seed=11, bag_path=bag, plan=PLAN, mode='direct')


def test_accepted_alignment_is_within_three_predicted_sigma_of_the_truth(nominal_run):
    # Issue must-show: residual LOS tilt within 3 sigma_R (3.32 with 3.37), turn about LOS within
    # 3 sigma_beta (3.34); residual = accepted matrix against /truth at the campaign elevation.
    summary = nominal_run.summary
    assert summary['accepted']
    residual, sigma = summary['residual_misalignment_arcsec'], summary['predicted_sigma_arcsec']
    for axis in ('el', 'xel', 'los'):
        assert abs(residual[axis]) <= 3.0 * sigma[axis], (axis, residual[axis], sigma[axis])
    # Scale check against Table 6.5: 1 px centroids give 1.2" (n = 18); 0.3" seeing averaged over
    # 3 frames with 4 maneuvers must land near 1-2".
    assert 0.5 < sigma['el'] < 3.0
    # The 2004-like truth starts about 1 deg and 20' off (eq. 6.1): the campaign really corrected it.
    assert np.hypot(residual['el'], residual['xel']) < 10.0 and abs(residual['los']) < 300.0


def test_run_writes_bag_and_the_documented_files(nominal_run):
    folder = nominal_run.bag_path
    for name in ('metadata.yaml', 'truth.yaml', 'model.yaml', 'calibration.yaml', 'summary.json'):
        assert (folder / name).exists(), name
    summary = json.loads((folder / 'summary.json').read_text())
    assert {'sim_seconds', 'wall_seconds', 'accepted', 'residual_misalignment_arcsec',
            'predicted_sigma_arcsec'} <= set(summary)
    assert (folder / 'truth.yaml').read_text() == NOMINAL.text


def test_bag_opens_with_rosbags_and_mcap_and_counts_match(nominal_run):
    with AnyReader([nominal_run.bag_path]) as reader:
        rosbags_counts = {connection.topic: connection.msgcount for connection in reader.connections}
    mcap_counts, decoded = {}, 0
    factory = DecoderFactory()
    with open(next(nominal_run.bag_path.glob('*.mcap')), 'rb') as stream:
        for schema, channel, message in make_reader(stream).iter_messages():
            count = mcap_counts[channel.topic] = mcap_counts.get(channel.topic, 0) + 1
            # mcap's own ROS 2 decoder reads every record; of the 400 Hz gyro samples (struct-made bytes, pinned
            # against the typestore's serializer in test_mode_bags) every 97th, which keeps this test short.
            if channel.topic != '/gyro_box/imu' or count % 97 == 1:
                assert factory.decoder_for(channel.message_encoding, schema)(message.data) is not None
                decoded += 1
    assert {t: c for t, c in rosbags_counts.items() if c} == mcap_counts
    assert decoded > 40000
    sim_s = nominal_run.summary['sim_seconds']
    ticks = int(round(sim_s / (DEFAULT_TICK_NS / 1e9)))
    assert rosbags_counts['/clock'] == ticks
    assert rosbags_counts['/gyro_box/imu'] == round(400 * sim_s)  # one sensor_msgs/Imu per 400 Hz sample
    for topic in ('/truth/imu', '/tascu/attitude', '/tascu/fd_command', '/tascu/motion_status'):
        assert rosbags_counts[topic] == ticks, topic
    assert rosbags_counts['/hipo/centroids'] == pytest.approx(sim_s, abs=1)  # 1 Hz frames


def test_every_topic_of_the_graph_is_recorded(nominal_run):
    topics = graph_topics(build_cores(graph_config(NOMINAL, 11, PLAN)))
    published = {topic for topic, (_, publisher, _) in topics.items() if publisher}
    with BagReader(nominal_run.bag_path) as bag:
        recorded = {topic.name for topic in bag.topics}
    assert published <= recorded
    assert {'/config/truth', '/config/model', '/parameter_events'} <= recorded


def test_offline_fits_from_the_bag_equal_the_live_ones(nominal_run):
    live = yaml.safe_load(nominal_run.result_yaml)
    fits = refit_alignments(nominal_run.bag_path)
    gyro = [fit for fit in fits if fit.purpose == 'gyro_alignment'][-1].fit
    np.testing.assert_array_equal(gyro.dcm, np.array(live['tarf_from_gyrf']))
    assert [fit.purpose for fit in fits][:3] == ['los_tilt', 'gyro_alignment', 'verification']


def test_same_seed_gives_the_same_bag(tmp_path):
    plan = AlignmentPlan(repetitions=2, verification_repetitions=1, drift_track_s=10.0)
    first = run_alignment(NOMINAL, seed=5, bag_path=tmp_path / 'a', plan=plan, mode='direct', max_sim_s=120)
    second = run_alignment(NOMINAL, seed=5, bag_path=tmp_path / 'b', plan=plan, mode='direct', max_sim_s=120)
    other = run_alignment(NOMINAL, seed=6, bag_path=tmp_path / 'c', plan=plan, mode='direct', max_sim_s=120)
    reference = _contents(first.bag_path)  # read once: every message of the run, compared with the two others
    assert reference == _contents(second.bag_path)
    assert reference != _contents(other.bag_path)


def _contents(path):
    with BagReader(path) as bag:
        return [(topic, stamp, bytes(data)) for topic, stamp, data in bag.raw_messages()]


def test_boresight_series_over_elevation_measures_the_fem_differential_flexure(nominal_run):
    # Table 3.5 / 6.2: with the FEM flexure in the truth, the FFI boresight moves against HIPO by
    # the FEM's 8.96" in XEL between 23 and 60 deg (6.2 measured ~9"); the FPI, at the focal
    # plane like HIPO, does not move (FEM ~0.1").
    flexure = yaml.safe_load(nominal_run.result_yaml)['flexure']
    elevations = [point['elevation_deg'] for point in flexure['points']]
    assert min(elevations) < 26.0 and max(elevations) > 55.0 and len(elevations) >= 4
    ffi_change = flexure['fit']['ffi']['change_23_to_60_deg_arcsec']
    assert ffi_change[1] == pytest.approx(8.96, abs=1.5)
    assert ffi_change[0] == pytest.approx(-3.24, abs=1.5)
    fpi_change = flexure['fit']['fpi']['change_23_to_60_deg_arcsec']
    assert np.hypot(*fpi_change) < 1.0
