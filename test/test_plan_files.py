"""Plan files (docs/plans.md): written, checked before the run, flown by the node graph, recorded with the bag."""

import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

from sofia_ros.bag import BagReader
from sofia_ros import cli
from sofia_ros.campaigns.graph_params import plan_from_parameters
from sofia_ros.campaigns.plan_files import PLAN_TYPES, read_plan, read_plan_file, write_plan_file
from sofia_ros.campaigns.registry import CAMPAIGNS, campaign_named
from sofia_ros.campaigns.run_parameters import plan_parameters
from sofia_ros.cli import main
from sofia_ros.compare.observations import read_observations
from sofia_ros.errors import ConfigError
from sofia_ros.sensors.imager_model import nominal_detector
from sofia_ros.sim.calibration import AlignmentPlan
from sofia_ros.sim.sequence import plan_text
from sofia_ros.sim.star_hop import StarHopPlan, table_d3_offsets_s
from sofia_ros.topics import PLAN_DOCUMENT

ROOT = Path(__file__).resolve().parents[1]
TRUTH = str(ROOT / 'config' / 'truth' / 'nominal.yaml')
ALIGNMENT_ELEMENTS = ('[{maneuvers: {elevation_deg: 45, repetitions: 1}}, {los_rotations: {angles_deg: [-2, 0.5, 2]}}, '
                      '{hold: {duration_s: 30, los_deg: 1.5, elevation_deg: 40}}]')
STAR_HOP_ELEMENTS = ('[{hold: {star: Polaris, duration_s: 20}}, '
                     '{hold: {star: Xi Cep, duration_s: 10, camera: fpi, detector_offset_arcsec: [120, -80]}}]')
PLANS = {
    'alignment with elements': AlignmentPlan(repetitions=3, flexure_elevations_deg=(25.0,),
                                             elements_yaml=ALIGNMENT_ELEMENTS),
    'star hop with elements': StarHopPlan(observations=table_d3_offsets_s()[15:17], hold_s=5.0, follow_times=False,
                                          elements_yaml=STAR_HOP_ELEMENTS),
    **{f'{name} {variant}': campaign_named(name).plan(variant)
       for name in ('alignment', 'star-hop') for variant in CAMPAIGNS[name].variants},
}


# --- the format -----------------------------------------------------------------------------------
@pytest.mark.parametrize('plan', PLANS.values(), ids=PLANS)
def test_a_plan_written_to_a_file_reads_back_equal(plan, tmp_path):
    path = write_plan_file(plan, tmp_path / 'plan.yaml')
    assert read_plan_file(path, plan.campaign) == plan
    # As node parameters too (--processes): the elements pass as one string parameter.
    assert plan_from_parameters(plan.campaign, plan_parameters(plan)) == plan


def test_an_empty_array_of_a_plan_passes_through_a_params_file(tmp_path):
    # `--processes` could not fly the minimal alignment (flexure_elevations_deg: []): rcl reads an empty array of a
    # params file as unset, and the nodes refused it ("must be an array of numbers, got None"), exit 3.
    script = f"""
import rclpy
from sofia_ros.campaigns.graph_params import plan_from_parameters
from sofia_ros.campaigns.registry import campaign_named
from sofia_ros.campaigns.run_parameters import plan_parameters
from sofia_ros.nodes.executables import _read_parameters
from sofia_ros.nodes.launch import write_params_file
from pathlib import Path
plan = campaign_named('alignment').plan('minimal')
path = Path({str(tmp_path / 'params.yaml')!r})
write_params_file(path, plan_parameters(plan))
rclpy.init(args=['--ros-args', '--params-file', str(path)])
values = _read_parameters('plant')
rclpy.shutdown()
assert values['plan.flexure_elevations_deg'] is None
assert plan_from_parameters('alignment', {{k: v for k, v in values.items() if k.startswith('plan.')}}) == plan
print('same plan')
"""
    done = subprocess.run([sys.executable, '-c', script], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0 and done.stdout == 'same plan\n', done.stderr[-2000:]


def test_the_named_variants_are_the_plan_files_under_config_plans():
    assert campaign_named('alignment').plan('minimal') == AlignmentPlan(
        repetitions=2, verification_repetitions=1, frames_per_position=1, drift_track_s=5.0,
        flexure_elevations_deg=(), max_iterations=1)
    assert campaign_named('star-hop').plan('reduced') == StarHopPlan(observations=table_d3_offsets_s()[3:7])
    assert campaign_named('alignment').plan() == AlignmentPlan() and campaign_named('star-hop').plan() == StarHopPlan()
    shipped = {path.stem for path in (ROOT / 'config' / 'plans').glob('*.yaml')}
    assert shipped == {f'{name}-{variant}' for name, spec in CAMPAIGNS.items() for variant in spec.variants}
    assert PLAN_TYPES == {name: spec.plan_type for name, spec in CAMPAIGNS.items() if spec.plan_type is not None}


def test_without_config_plans_sofia_run_flies_the_thesis_plan_and_names_what_is_missing(monkeypatch):
    # An install whose share/ lacks config/plans (an older setup.py): the default plan needs no file.
    from sofia_ros import input_files

    monkeypatch.setattr(input_files, '__file__', '/nowhere/sofia_ros/input_files.py')  # where shipped_paths looks
    monkeypatch.setattr('sys.prefix', '/nowhere')
    spec = campaign_named('alignment')
    arguments = ['run', 'alignment', '--truth', TRUTH, '--bag', 'bag', '--repetitions', '4']
    assert cli._plan(spec, cli.build_parser().parse_args(arguments), repetitions=4) == AlignmentPlan(repetitions=4)
    with pytest.raises(ConfigError, match=r'the named plans \(config/plans\) are not installed here; give a plan '):
        cli._plan(spec, cli.build_parser().parse_args([*arguments, '--variant', 'reduced']))


def test_elements_are_kept_in_one_spelling():
    spelled = AlignmentPlan(elements_yaml='- hold: {duration_s: 30}\n')
    assert spelled == AlignmentPlan(elements_yaml='[{hold: {duration_s: 30.0, los_deg: 0}}]')
    assert spelled.elements[0].duration_s == 30.0 and spelled.elements[0].elevation_deg is None


# --- checked before the run -------------------------------------------------------------------------
BAD_PLANS = {
    'unknown key': ('alignment', 'campaign: alignment\nrepetition: 2\n',
                    r"unknown key 'repetition' in the alignment plan; it takes campaign, repetitions"),
    'unknown maneuver': ('alignment', 'campaign: alignment\nelements:\n  - spin: {angle_deg: 3}\n',
                         r"element 1: unknown maneuver 'spin' for the alignment campaign; use one of maneuvers, "
                         r'los_rotations, hold'),
    'unknown element field': ('star-hop', 'campaign: star-hop\nelements:\n  - hold: {star: Polaris, duration: 3}\n',
                              r'element 1 \(hold\): unknown field duration; hold takes star, duration_s'),
    'element missing a field': ('alignment', 'campaign: alignment\nelements:\n  - maneuvers: {repetitions: 2}\n',
                                r'element 1 \(maneuvers\) needs elevation_deg'),
    'element elevation too high': ('alignment', 'campaign: alignment\nelements:\n  - maneuvers: {elevation_deg: 65}\n',
                                   r'elevation_deg is 65 deg, outside the 20-60 deg elevations'),
    'hold elevation too low': ('alignment', 'campaign: alignment\nelements:\n'
                                            '  - hold: {duration_s: 5, elevation_deg: 19.5}\n',
                               r'elevation_deg is 19.5 deg, outside the 20-60 deg'),
    'series elevation too high': ('alignment', 'campaign: alignment\nflexure_elevations_deg: [23, 61]\n',
                                  r'flexure_elevations_deg is 61 deg, outside the 20-60 deg'),
    'LOS angle beyond the fine drive': ('alignment', 'campaign: alignment\nelements:\n'
                                                     '  - hold: {duration_s: 5, los_deg: -3.5}\n',
                                        r"los_deg is -3.5 deg, outside the fine drive's \+-3 deg LOS travel"),
    'LOS rotation beyond the fine drive': ('alignment', 'campaign: alignment\nelements:\n'
                                                        '  - los_rotations: {angles_deg: [0, 3.2]}\n',
                                           r"angles_deg\[1\] is 3.2 deg, outside the fine drive's"),
    'hold of 0 s': ('alignment', 'campaign: alignment\nelements:\n  - hold: {duration_s: 0}\n',
                    r'duration_s must be > 0 and <= 7200 s, got 0'),
    'negative star-hop hold': ('star-hop', 'campaign: star-hop\nelements:\n  - hold: {star: Polaris, duration_s: -5}\n',
                               r'duration_s must be > 0 and <= 7200 s, got -5'),
    'hold_s of 0': ('star-hop', 'campaign: star-hop\nhold_s: 0\n', r'hold_s must be positive'),
    # Huge but finite values overflowed the clock into a traceback and a half-written bag; values the options of
    # `sofia run` refuse failed in the middle of the run, at exit 0 (plan_limits).
    'a hold of 1e300 s': ('alignment', 'campaign: alignment\nelements:\n  - hold: {duration_s: 1.0e+300}\n',
                          r'duration_s must be > 0 and <= 7200 s, got 1e\+300'),
    'a timeout of 1e300 s': ('alignment', 'campaign: alignment\ntimeout_s: 1.0e+300\n',
                             r'timeout_s must be > 0 and <= 3600 s, got 1e\+300'),
    'a star-hop hold of 1e300 s': ('star-hop', 'campaign: star-hop\nhold_s: 1.0e+300\n',
                                   r'hold_s must be > 0 and <= 7200 s'),
    'an observation a year later': ('star-hop', 'campaign: star-hop\nobservations: [[Polaris, 0], [Alpha Cep, 3.2e+7]]\n',
                                    r'offsets must be >= 0 and <= 86400 s'),
    'no drift track': ('alignment', 'campaign: alignment\ndrift_track_s: 0\n', r'drift_track_s must be 1-3600 s'),
    'repetitions past the options': ('alignment', 'campaign: alignment\nrepetitions: 100000000000\n',
                                     r'repetitions must be 2-100 maneuvers per axis'),
    'no iteration': ('alignment', 'campaign: alignment\nmax_iterations: 0\n', r'max_iterations must be 1-20'),
    'a negative timeout': ('star-hop', 'campaign: star-hop\ntimeout_s: -1\n', r'timeout_s must be > 0'),
    'no frame on the star hop': ('star-hop', 'campaign: star-hop\nframes_per_position: 0\n',
                                 r'frames_per_position must be 1-100 frames'),
    'EL/XEL rotations beyond HIPO': ('alignment', 'campaign: alignment\nelxel_length_arcmin: 600\n',
                                     r"elxel_length_arcmin must be > 0 and <= 5.05 arcmin, the rotations crossing "
                                     r"HIPO's field"),
    'a number as text': ('alignment', 'campaign: alignment\nelements:\n  - hold: {duration_s: "40"}\n',
                         r"duration_s must be a number, got the text '40' \(write it without quotes\)"),
    'an exponent YAML reads as text': ('alignment', 'campaign: alignment\ndrift_track_s: 1e3\n',
                                       r'write 1000 or 1.0e\+3'),
    'star not in the catalogue': ('star-hop',
                                  'campaign: star-hop\nelements:\n  - hold: {star: Vega Prime, duration_s: 5}\n',
                                  r"element 1 \(hold\): unknown star name 'Vega Prime'"),
    'observed star not in the catalogue': ('star-hop',
                                           'campaign: star-hop\nobservations: [[Polaris, 0], [Vulcan, 60]]\n',
                                           r"unknown star name 'Vulcan'"),
    'position off the detector': ('star-hop', 'campaign: star-hop\nelements:\n  - hold: {star: Polaris, duration_s: 5, '
                                              'camera: fpi, detector_offset_arcsec: [400, 0]}\n',
                                  r'detector_offset_arcsec \[400.0, 0.0\] leaves the FPI field'),
    'a plan of the other campaign': ('alignment', 'campaign: star-hop\nhold_s: 5\n',
                                     r'is a plan of the star-hop campaign, not of alignment; give a plan of the '
                                     r'alignment campaign, or fly this one with `sofia run star-hop --plan'),
    'an unknown campaign': ('alignment', 'campaign: Alignment\nrepetitions: 2\n',
                            r"campaign is 'Alignment'; a plan is for one of alignment, star-hop"),
    'no campaign': ('alignment', 'repetitions: 2\n', r'a plan file is a mapping that starts with campaign:'),
    'a thermal step': ('alignment', 'campaign: alignment\nelements:\n  - temperature_ramp: {slope_c_per_h: -3}\n',
                       r"element temperature_ramp: the simulated temperature follows the truth's scenario"),
    'wrong type': ('alignment', 'campaign: alignment\nrepetitions: two\n', r'repetitions must be an integer'),
    'not a finite number': ('alignment', 'campaign: alignment\ndrift_track_s: .nan\n',
                            r'drift_track_s must be a finite number'),
    'a row that is not [star, offset_s]': ('star-hop', 'campaign: star-hop\nobservations: [[Polaris], [Xi Cep, 60]]\n',
                                           r'observations\[0\] must be a list of 2 values'),
    'true for a number': ('alignment', 'campaign: alignment\nelements:\n  - hold: {duration_s: true}\n',
                          r'duration_s must be a number, got True'),
    'an element without fields': ('alignment', 'campaign: alignment\nelements:\n  - hold:\n',
                                  r'element 1 \(hold\) must map its fields \(duration_s, los_deg, elevation_deg\)'),
    'elements not a list': ('alignment', 'campaign: alignment\nelements: {hold: {duration_s: 5}}\n',
                            r'elements must be a list'),
    'not YAML': ('alignment', 'campaign: [alignment\n', r'not valid YAML'),
}


@pytest.mark.parametrize('campaign, text, message', BAD_PLANS.values(), ids=BAD_PLANS)
def test_a_bad_plan_is_one_config_error(campaign, text, message, tmp_path):
    path = tmp_path / 'plan.yaml'
    path.write_text(text)
    with pytest.raises(ConfigError, match=message):
        read_plan_file(path, campaign)


@pytest.mark.parametrize('campaign, text, message', BAD_PLANS.values(), ids=BAD_PLANS)
def test_sofia_run_refuses_a_bad_plan_before_it_writes_anything(campaign, text, message, tmp_path, capsys):
    path = tmp_path / 'plan.yaml'
    path.write_text(text)
    bag = tmp_path / 'bag'
    code = main(['run', campaign, '--truth', TRUTH, '--plan', str(path), '--bag', str(bag), '--direct'])
    captured = capsys.readouterr()
    assert code == 2
    lines = captured.err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith('sofia: error: ') and 'Traceback' not in captured.err
    assert re.search(message, lines[0])
    assert not bag.exists() and captured.out == ''


@pytest.mark.parametrize('argv, message', [
    (['alignment', '--variant', 'tiny'], r"no variant 'tiny'; use one of full, reduced, minimal"),
    (['gyro-stability', '--case', 'TC-1', '--variant', 'reduced'], r'has no plan; drop --plan / --variant'),
    (['alignment', '--plan', 'no-such-plan.yaml'], r'cannot read no-such-plan.yaml: no such file'),
])
def test_sofia_run_refuses_a_bad_plan_option_in_one_line(argv, message, tmp_path, capsys):
    code = main(['run', *argv, '--truth', TRUTH, '--bag', str(tmp_path / 'bag')])
    lines = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(lines) == 1
    assert re.search(message, lines[0])
    assert not (tmp_path / 'bag').exists()


def test_a_bag_without_a_plan_is_one_line(tmp_path):
    with pytest.raises(ConfigError, match=r'has no plan.yaml: it was not recorded by `sofia run` with plans'):
        read_plan(tmp_path)


# --- flown: the elements are in the bag as observations compare reads ------------------------------
def _fly(tmp_path_factory, campaign, text, *options):
    folder = tmp_path_factory.mktemp(campaign)
    (folder / 'plan.yaml').write_text(text)
    bag = folder / 'bag'
    assert main(['run', campaign, '--truth', TRUTH, '--seed', '2', '--plan', str(folder / 'plan.yaml'),
                 '--bag', str(bag), '--direct', *options]) == 0
    return folder / 'plan.yaml', bag


@pytest.fixture(scope='module')
def alignment_flown(tmp_path_factory):
    """The minimal alignment with a hold at LOS +1.5 deg and LOS rotations through -2, 0.5 and 2 deg."""
    minimal = (ROOT / 'config' / 'plans' / 'alignment-minimal.yaml').read_text()
    return _fly(tmp_path_factory, 'alignment', minimal + 'elements:\n  - hold: {duration_s: 20, los_deg: 1.5}\n'
                                                         '  - los_rotations: {angles_deg: [-2, 0.5, 2]}\n')


@pytest.fixture(scope='module')
def star_hop_flown(tmp_path_factory):
    """Two observations held 5 s, then Xi Cep held 10 s at (120", -80") from the FPI's centre."""
    text = ('campaign: star-hop\nobservations: [[Polaris, 5494.0], [Xi Cep, 5687.0]]\nhold_s: 5\nfollow_times: false\n'
            'elements:\n  - hold: {star: Xi Cep, duration_s: 10, camera: fpi, detector_offset_arcsec: [120, -80]}\n')
    return _fly(tmp_path_factory, 'star-hop', text)


def _window_rows(observations, element, camera='hipo'):
    centroids = observations.centroids
    in_window = (centroids.stamp_s >= element['hold_start_s']) & (centroids.stamp_s <= element['hold_end_s'])
    return in_window & (centroids.camera_index == centroids.cameras.index(camera))


def test_an_alignment_hold_and_los_rotations_are_rows_of_the_bag(alignment_flown):
    plan_path, bag = alignment_flown
    result = yaml.safe_load((bag / 'calibration.yaml').read_text())
    hold, rotations = result['elements']
    assert [hold['kind'], rotations['kind']] == ['hold', 'los_rotations'] and rotations['los_maneuvers'] == 2
    observations = read_observations(bag)
    rows = _window_rows(observations, hold)
    # HIPO's frames through the hold's 20 s, at the planned LOS angle (the Earth's turn walks it a little).
    assert rows.sum() >= 15
    assert np.all(np.abs(observations.centroids.fd_los_deg[rows] - 1.5) < 0.2)
    gyro = observations.gyro
    during = (gyro.tick_mean_time_s > rotations['start_s']) & (gyro.tick_mean_time_s < rotations['end_s'])
    # The LOS rotations turn the gyros' LOS axis: 2.5 and 1.5 deg at the fine drive's rate.
    los_rates_deg_per_s = np.degrees(gyro.tick_mean_rates_gyrf_rad_per_s[during, 2])
    assert np.max(np.abs(los_rates_deg_per_s)) > 0.05
    assert read_plan(bag) == read_plan_file(plan_path)
    with BagReader(bag) as reader:
        assert reader.document(PLAN_DOCUMENT.name) == (bag / 'plan.yaml').read_text() == plan_text(read_plan(bag))


def test_a_star_hop_hold_on_a_detector_position_is_rows_of_the_bag(star_hop_flown):
    plan_path, bag = star_hop_flown
    summary = yaml.safe_load((bag / 'summary.json').read_text())
    assert summary['finished'] and summary['observations'] == 2 and summary['elements'] == 1
    (hold,) = yaml.safe_load((bag / 'star_hop.yaml').read_text())['elements']
    observations = read_observations(bag)
    rows = _window_rows(observations, hold, 'fpi')
    assert rows.sum() >= 5  # the FPI frames of the 10 s hold
    fpi = nominal_detector('fpi')
    target_px = np.asarray(fpi.center_px) + np.array([120.0, -80.0]) / fpi.scale_arcsec_per_px
    # Where the plan put it, to a few pixels (the inertial hold drifts with the gyro bias).
    assert np.all(np.linalg.norm(observations.centroids.measured_px[rows] - target_px, axis=1) < 5.0)
    assert read_plan(bag) == read_plan_file(plan_path)


@pytest.mark.parametrize('name, value', [('seed', -1), ('seed', 'abc'), ('tick_ns', 0), ('tick_ns', -200_000_000),
                                         ('max_sim_s', -5.0), ('stall_timeout_s', 0.0)])
def test_a_node_executable_refuses_run_parameters_out_of_range(name, value):
    # Started by hand (`ros2 run sofia_ros clock -p tick_ns:=0`): a traceback, or a node waiting for ever.
    from sofia_ros.campaigns.graph_params import GRAPH_PARAMETERS, graph_config_from_parameters

    values = {key: default for key, (default, _) in GRAPH_PARAMETERS.items()}
    values.update(truth_file=str(ROOT / 'config' / 'truth' / 'nominal.yaml'), **{name: value})
    with pytest.raises(ConfigError, match=f'parameter {name} must be'):
        graph_config_from_parameters(values)
