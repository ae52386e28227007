"""`sofia perturb` on a reduced alignment campaign: exactly one field changes, by the shape; bad input writes nothing.

The campaign is the Table 3.4 sequence in direct mode with 2 repetitions, 1 verification, 10 s of
drift tracking and no boresight series (about 420 s of sim time, all four cameras), recorded once.
"""

import struct
from pathlib import Path

import numpy as np
import pytest
import yaml
from mcap.reader import make_reader
from mcap.records import Chunk
from mcap.stream_reader import StreamReader

from sofia_ros import messages as m
from sofia_ros.bag import BagReader, BagWriter
from sofia_ros.bag.msgtypes import decode_cdr
from sofia_ros.campaigns.alignment import run_alignment
from sofia_ros.cli import main
from sofia_ros.compare.observations import read_observations
from sofia_ros.config import load_effect_config
from sofia_ros.errors import BagError, PerturbationError
from sofia_ros.perturb import PERTURBATION_FILE, Perturbation, perturb_bag
from sofia_ros.sensors.imager_model import nominal_detector
from sofia_ros.sim.calibration import AlignmentPlan
from sofia_ros.units import RAD_PER_ARCSEC, RAD_PER_DEG

ROOT = Path(__file__).resolve().parents[1]
PLAN = AlignmentPlan(repetitions=2, verification_repetitions=1, drift_track_s=10.0, flexure_elevations_deg=())
IMU = '/gyro_box/imu'
SIDE_FILES = ('metadata.yaml', 'truth.yaml', 'model.yaml', 'calibration.yaml', 'summary.json')


@pytest.fixture(scope='module')
def bag(tmp_path_factory):
    path = tmp_path_factory.mktemp('campaign') / 'bag'
    run_alignment(load_effect_config(ROOT / 'config' / 'truth' / 'nominal.yaml'), seed=3, bag_path=path, plan=PLAN,
                  mode='direct')
    return path


def _mcap(path):
    return next(Path(path).glob('*.mcap'))


def _records(path):
    """Schemas, channels, metadata, attachments and every message (file order) of a bag's MCAP file."""
    with open(_mcap(path), 'rb') as file:
        reader = make_reader(file, validate_crcs=True)
        summary = reader.get_summary()
        schemas = {(s.id, s.name, s.encoding, s.data) for s in summary.schemas.values()}
        channels = {(c.id, c.topic, c.message_encoding, c.schema_id, tuple(c.metadata.items()))
                    for c in summary.channels.values()}
        metadata = [(item.name, item.metadata) for item in reader.iter_metadata()]
        attachments = [(a.name, a.data) for a in reader.iter_attachments()]
        messages = [(channel.topic, msg.log_time, msg.publish_time, msg.sequence, bytes(msg.data))
                    for _, channel, msg in reader.iter_messages(log_time_order=False)]
    return schemas, channels, metadata, attachments, messages


def _assert_only_topic_changed(source, out, topic):
    """Every record of ``out`` equals ``source``'s but the payloads of ``topic``; returns those payload pairs."""
    before, after = _records(source), _records(out)
    assert before[:4] == after[:4]
    assert len(before[4]) == len(after[4])
    pairs = []
    for old, new in zip(before[4], after[4]):
        assert old[:4] == new[:4]
        if old[0] == topic:
            pairs.append((old[4], new[4]))
        else:
            assert old[4] == new[4], old[0]
    for name in SIDE_FILES:
        assert (out / name).read_bytes() == (source / name).read_bytes(), name
    return pairs


def _doubles(data):
    return np.frombuffer(bytes(data), dtype=np.uint8)


def test_a_camera_axis_changes_by_the_shape_in_px_and_nothing_else(bag, tmp_path):
    out = tmp_path / 'fpi_y'
    result = perturb_bag(bag, out, 'fpi.y', '0.5 + 0.001*detector_x_px - 0.0001*hip*0')
    pairs = _assert_only_topic_changed(bag, out, '/fpi/centroids')
    scale = nominal_detector('fpi').scale_arcsec_per_px
    old_y, new_y, added = [], [], []
    for old, new in pairs:
        old_msg, new_msg = decode_cdr(old, 'geometry_msgs/msg/PoseArray'), decode_cdr(new, 'geometry_msgs/msg/PoseArray')
        assert (old_msg.header.stamp.sec, old_msg.header.stamp.nanosec, old_msg.header.frame_id) == (
            new_msg.header.stamp.sec, new_msg.header.stamp.nanosec, new_msg.header.frame_id)
        assert len(old_msg.poses) == len(new_msg.poses)
        for a, b in zip(old_msg.poses, new_msg.poses):
            # Unchanged fields bit for bit: position x, z and the orientation.
            assert struct.pack('<6d', a.position.x, a.position.z, a.orientation.x, a.orientation.y,
                               a.orientation.z, a.orientation.w) == struct.pack(
                '<6d', b.position.x, b.position.z, b.orientation.x, b.orientation.y, b.orientation.z, b.orientation.w)
            old_y.append(a.position.y)
            new_y.append(b.position.y)
            added.append(0.5 + 0.001 * a.position.x)
    added = np.array(added)
    np.testing.assert_allclose(np.array(new_y) - np.array(old_y), added / scale, rtol=1e-9, atol=1e-12)
    assert result == Perturbation('fpi.y', '0.5 + 0.001*detector_x_px - 0.0001*hip*0', 'arcsec', len(added),
                                  pytest.approx(float(np.sqrt(np.mean(added ** 2)))), pytest.approx(added.min()),
                                  pytest.approx(added.max()))
    record = yaml.safe_load((out / PERTURBATION_FILE).read_text())
    assert record['observable'] == 'fpi.y' and record['unit'] == 'arcsec' and record['rows_changed'] == len(added)
    assert record['source_bag'] == str(bag.resolve())


def test_a_gyro_axis_changes_by_a_specific_force_shape_and_only_its_eight_bytes(bag, tmp_path):
    out = tmp_path / 'gyro_el'
    result = perturb_bag(bag, out, 'gyro.el', '3.0*specific_force_x_m_per_s2 + 0.1*specific_force_z_m_per_s2')
    pairs = _assert_only_topic_changed(bag, out, IMU)
    with BagReader(bag) as source, BagReader(out) as copy:
        before, after = source.imu_arrays(IMU), copy.imu_arrays(IMU)
    force = before.linear_acceleration_m_per_s2
    added_deg_per_h = 3.0 * force[:, 0] + 0.1 * force[:, 2]
    np.testing.assert_allclose(after.angular_velocity_rad_per_s[:, 0] - before.angular_velocity_rad_per_s[:, 0],
                               added_deg_per_h * RAD_PER_DEG / 3600.0, rtol=1e-6, atol=1e-18)
    assert np.array_equal(after.angular_velocity_rad_per_s[:, 1:], before.angular_velocity_rad_per_s[:, 1:])
    assert np.array_equal(after.linear_acceleration_m_per_s2, force)
    assert np.array_equal(after.header_stamp_ns, before.header_stamp_ns)
    # Byte for byte, each sample differs at most in the 8 bytes of angular_velocity.x.
    for old, new in pairs[::97]:
        differ = np.flatnonzero(_doubles(old) != _doubles(new))
        assert len(differ) == 0 or differ.max() - differ.min() < 8
    assert result.rows_changed == np.count_nonzero(added_deg_per_h) and result.unit == 'deg_per_h'
    assert result.max == pytest.approx(added_deg_per_h.max())


def test_a_constant_and_a_step_in_time(bag, tmp_path):
    constant = perturb_bag(bag, tmp_path / 'constant', 'gyro.xel', '1.5', unit='arcsec_per_s')
    with BagReader(bag) as source, BagReader(tmp_path / 'constant') as copy:
        before, after = source.imu_arrays(IMU), copy.imu_arrays(IMU)
        campaign_start_ns = source.campaign_epoch_ns()
    np.testing.assert_allclose(after.angular_velocity_rad_per_s[:, 1] - before.angular_velocity_rad_per_s[:, 1],
                               1.5 * RAD_PER_ARCSEC, rtol=1e-6)
    assert (constant.rows_changed, constant.rms, constant.min, constant.max) == (len(before.stamp_ns), 1.5, 1.5, 1.5)

    step = perturb_bag(bag, tmp_path / 'step', 'hipo.x', '2.0*(time_s > 200)', unit='px')
    old, new = read_observations(bag).centroids, read_observations(tmp_path / 'step').centroids
    hipo = old.camera_index == old.cameras.index('hipo')
    # read_observations gives seconds from the campaign start, as time_s counts.
    time_s = old.stamp_s
    expected = np.where(hipo & (time_s > 200.0), 2.0, 0.0)
    np.testing.assert_allclose(new.measured_px[:, 0] - old.measured_px[:, 0], expected, atol=1e-9)
    assert np.array_equal(new.measured_px[:, 1], old.measured_px[:, 1])
    with BagReader(bag) as source:
        pose_time_s = np.array([(m.stamp_ns_of(msg.header.stamp) - campaign_start_ns) / 1e9
                                for _, _, msg in source.messages('/hipo/centroids') for _ in msg.poses])
    after_step = np.count_nonzero(pose_time_s > 200.0)
    assert 0 < after_step < len(pose_time_s)
    assert (step.rows_changed, step.min, step.max) == (after_step, 0.0, 2.0)
    assert step.rms == pytest.approx(2.0 * np.sqrt(after_step / len(pose_time_s)))


def test_variables_match_what_compare_reads_and_the_temperature_holds_its_last_value(bag, tmp_path):
    perturb_bag(bag, tmp_path / 'el', 'wfi.x', 'elevation_deg', unit='px')
    perturb_bag(bag, tmp_path / 'los', 'wfi.y', 'los_angle_deg + 100*temperature_c', unit='px')
    old = read_observations(bag)
    el, los = read_observations(tmp_path / 'el'), read_observations(tmp_path / 'los')
    wfi = old.centroids.camera_index == old.centroids.cameras.index('wfi')
    np.testing.assert_allclose((el.centroids.measured_px - old.centroids.measured_px)[wfi, 0],
                               old.centroids.elevation_deg[wfi], rtol=1e-9)
    with BagReader(bag) as source:
        # In seconds from the campaign start, as read_observations gives the centroid stamps.
        campaign_start_ns = source.campaign_epoch_ns()
        temps = [((m.stamp_ns_of(msg.header.stamp) - campaign_start_ns) / 1e9, msg.temperature)
                 for _, _, msg in source.messages('/gyro_box/temperature')]
    stamps, values = np.array(temps).T
    # At or before, to 1 us: a frame stamped on a tick reads that tick's value, whatever the float rounding.
    last = values[np.clip(np.searchsorted(stamps, old.centroids.stamp_s[wfi] + 1e-6, side='right') - 1, 0, None)]
    np.testing.assert_allclose((los.centroids.measured_px - old.centroids.measured_px)[wfi, 1],
                               old.centroids.fd_los_deg[wfi] + 100.0 * last, rtol=1e-9)


def test_the_copy_reads_like_the_source_in_bagreader_and_compare(bag, tmp_path):
    out = tmp_path / 'copy'
    perturb_bag(bag, out, 'ffi.x', '0.3*sin(2*pi*time_s/120)')
    with BagReader(bag) as source, BagReader(out) as copy:
        assert copy.topics == source.topics
        assert copy.document('/config/truth') == source.document('/config/truth')
    with open(_mcap(out), 'rb') as file:
        summary = make_reader(file).get_summary()
        assert summary.statistics.chunk_count == len(summary.chunk_indexes) > 1
        assert {chunk.compression for chunk in summary.chunk_indexes} == {'zstd'}
        file.seek(0)
        chunks = [record for record in StreamReader(file, emit_chunks=True).records if isinstance(record, Chunk)]
        assert len(chunks) == len(summary.chunk_indexes) and all(chunk.uncompressed_crc for chunk in chunks)
    old, new = read_observations(bag), read_observations(out)
    ffi = old.centroids.camera_index == old.centroids.cameras.index('ffi')
    changed = np.any(new.centroids.measured_px != old.centroids.measured_px, axis=1)
    assert changed.any() and not changed[~ffi].any()
    assert np.array_equal(new.gyro.tick_mean_rates_gyrf_rad_per_s, old.gyro.tick_mean_rates_gyrf_rad_per_s)
    assert np.array_equal(new.gyro.within_tick_rate_sigma_rad_per_s, old.gyro.within_tick_rate_sigma_rad_per_s)


@pytest.fixture(scope='module')
def no_camera_bag(tmp_path_factory):
    path = tmp_path_factory.mktemp('clock_only') / 'bag'
    with BagWriter(path) as writer:
        writer.add_topic('/clock', 'rosgraph_msgs/msg/Clock')
        writer.write_message('/clock', m.clock_msg(0), 0)
    return path


BAD = [
    ('fpi.z', '1.0', None, PerturbationError, r"unknown observable 'fpi.z'; pick one of fpi.x"),
    ('fpi.x', 'flux_adu', None, PerturbationError, r"unknown variable 'flux_adu'.*known variables: time_s"),
    ('gyro.el', 'detector_x_px', None, PerturbationError, r"unknown variable 'detector_x_px'"),
    ('fpi.x', '2.0*(time_s >', None, PerturbationError, 'is not a valid expression'),
    ('fpi.x', "__import__('os')", None, PerturbationError, 'calls something other than the functions'),
    ('fpi.x', 'time_s.real', None, PerturbationError, 'uses Attribute, which is not allowed'),
    ('fpi.x', '[time_s][0]', None, PerturbationError, 'uses (Subscript|List), which is not allowed'),
    ('fpi.x', '(lambda: 1)()', None, PerturbationError, 'calls something other'),
    ('fpi.x', 'clip(time_s, a_min=0, a_max=1)', None, PerturbationError, 'keyword or starred'),
    ('fpi.x', 'sin', None, PerturbationError, 'without calling it'),
    ('fpi.x', 'heaviside(time_s)', None, PerturbationError, r'heaviside\(\) takes 2 argument'),
    ('fpi.x', '1' + '+1' * 300, None, PerturbationError, 'more than 500'),
    ('fpi.x', '1.0', 'deg_per_h', PerturbationError, r"unit 'deg_per_h' is not accepted for fpi.x; use one of arcsec, px"),
    ('gyro.los', '1.0', 'px', PerturbationError, 'use one of deg_per_h, arcsec_per_s'),
    ('fpi.x', 'log(-1 + 0*time_s)', None, PerturbationError, 'is not finite at'),
    ('fpi.x', '1/(time_s - time_s)', None, PerturbationError, 'is not finite at'),
    # Finite in arcsec, inf in pixels: the copy held inf at exit 0.
    ('fpi.x', '1.7e308', None, PerturbationError, 'beyond the numbers a bag can hold'),
    ('gyro.el', '1e300', None, PerturbationError, 'beyond the numbers a bag can hold'),
]


@pytest.mark.parametrize(('observable', 'shape', 'unit', 'error', 'match'), BAD, ids=[row[1][:30] for row in BAD])
def test_bad_input_raises_one_line_and_writes_nothing(bag, tmp_path, observable, shape, unit, error, match):
    with pytest.raises(error, match=match) as caught:
        perturb_bag(bag, tmp_path / 'out', observable, shape, unit=unit)
    assert '\n' not in str(caught.value)
    assert list(tmp_path.iterdir()) == []


def test_an_existing_out_or_a_missing_camera_is_refused(bag, no_camera_bag, tmp_path):
    (tmp_path / 'taken').mkdir()
    with pytest.raises(PerturbationError, match='already exists; pass a new directory'):
        perturb_bag(bag, tmp_path / 'taken', 'fpi.x', '1.0')
    with pytest.raises(BagError, match=r'lacks /wfi/centroids, so it has no wfi.x'):
        perturb_bag(no_camera_bag, tmp_path / 'out', 'wfi.x', '1.0')
    assert [path.name for path in tmp_path.iterdir()] == ['taken']


def test_cli_prints_one_line_and_exits_2_on_bad_input_leaving_nothing(bag, tmp_path, capsys):
    out = tmp_path / 'cli'
    assert main(['perturb', str(bag), str(out), '--observable', 'hipo.y', '--shape', '0.25']) == 0
    line = capsys.readouterr().out
    assert line.count('\n') == 1 and 'rows changed' in line and 'RMS 0.25, min 0.25, max 0.25 arcsec' in line
    assert main(['perturb', str(bag), str(tmp_path / 'bad'), '--observable', 'hipo.y',
                 '--shape', 'log(-1 + 0*time_s)']) == 2
    err = capsys.readouterr().err
    assert err.count('\n') == 1 and err.startswith('sofia: error: the shape') and 'keep it finite' in err
    assert [path.name for path in tmp_path.iterdir()] == ['cli']


def _damaged_copy(bag, tmp_path, name, at_fraction, length):
    """A copy of ``bag`` with ``length`` bytes inverted at ``at_fraction`` of its MCAP file (its metadata left)."""
    import shutil

    damaged = tmp_path / name
    shutil.copytree(bag, damaged)
    mcap = _mcap(damaged)
    data = bytearray(mcap.read_bytes())
    start = int(len(data) * at_fraction)
    data[start:start + length] = bytes(byte ^ 0xFF for byte in data[start:start + length])
    mcap.write_bytes(bytes(data))
    return damaged


@pytest.mark.parametrize('observable', ['fpi.x', 'gyro.el'])
def test_a_damaged_chunk_anywhere_is_refused_not_copied(bag, tmp_path, observable):
    # A chunk of other topics was copied as it was, its CRC unread: a perturbed bag that failed later, at exit 0.
    damaged = _damaged_copy(bag, tmp_path, 'damaged', 0.4, 50)
    with pytest.raises(BagError, match=r'truncated or corrupt|fails its CRC|damaged'):
        perturb_bag(damaged, tmp_path / 'out', observable, '1.0')
    assert not (tmp_path / 'out').exists()
    assert not [path for path in tmp_path.iterdir() if path.name.startswith('.out')]


def test_a_failure_in_the_middle_of_the_copy_is_its_own_error(bag, tmp_path, monkeypatch, capsys):
    import errno

    from sofia_ros.perturb import rewrite

    # A view of the mapped source outlived the failure: closing the map raised BufferError over it (exit 1).
    def full(self, position):
        raise OSError(errno.ENOSPC, 'No space left on device')

    monkeypatch.setattr(rewrite._Copy, '_footer', full)
    assert main(['perturb', str(bag), str(tmp_path / 'out'), '--observable', 'fpi.x', '--shape', '1.0']) == 3
    err = capsys.readouterr().err
    assert err.count('\n') == 1 and 'disk full' in err and 'BufferError' not in err, err

    def interrupted(self, position):
        raise KeyboardInterrupt

    monkeypatch.setattr(rewrite._Copy, '_footer', interrupted)
    with pytest.raises(KeyboardInterrupt):
        perturb_bag(bag, tmp_path / 'out', 'fpi.x', '1.0')
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize('command', ['perturb', 'recover', 'import'])
def test_an_output_inside_the_input_folder_is_refused(bag, tmp_path, capsys, command):
    # Each wrote a whole bag inside its input folder, at exit 0.
    argv = {'perturb': ['perturb', str(bag), str(bag / 'inner'), '--observable', 'fpi.x', '--shape', '1.0'],
            'recover': ['recover', str(bag), '--out', str(bag / 'inner')],
            'import': ['import', str(tmp_path), '--bag', str(tmp_path / 'inner')]}[command]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.count('\n') == 1 and 'is inside' in err, err
    assert not (bag / 'inner').exists() and not (tmp_path / 'inner').exists()
