"""`sofia atlas` without campaigns: the grid, the Parquet store, the statistics, the page, and every bad input."""

import io
import os
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest
from scipy.stats import beta

from sofia_ros.atlas.engine import Progress, checked_scheduler_address, dask_client
from sofia_ros.atlas.grid import grid_from_file, grid_from_lists, hidden_truth_text, scaled_params
from sofia_ros.atlas.report import summarize, text_table, write_html
from sofia_ros.atlas.stats import (DetectionPoint, TABLE_6_5, confusions, detectable_sizes, detection_curves,
                                   fit_calibration, table_6_5_slice)
from sofia_ros.atlas.store import ResultStore
from sofia_ros.atlas.task import ROW_FIELDS, reference_param
from sofia_ros.cli import main
from sofia_ros.config import parse_effect_config
from sofia_ros.errors import ConfigError, SchedulerUnreachableError, UnknownEffectError

REPO = Path(__file__).resolve().parents[1]
TINY = dict(effects=['timestamp_offset', 'imager_rotation_of_field'], sizes=[0.5, 2], campaigns=['alignment:minimal'],
            seeds=[1, 2])


def _row(**fields):
    row = {name: None for name in ROW_FIELDS}
    row.update(effect='timestamp_offset', size=1.0, campaign='alignment', variant='reduced', seed=1, detected=False)
    row.update(fields)
    row['key'] = f'{row["effect"]}|{row["size"]:g}|{row["campaign"]}|{row["variant"]}|{row["seed"]}'
    return row


# --- the grid ---------------------------------------------------------------------------------------------------

def test_the_grid_is_every_cell_once_with_a_key_each():
    grid = grid_from_lists(**TINY)
    tasks = grid.tasks()
    assert len(tasks) == 8 and len({task.key for task in tasks}) == 8
    assert tasks[0].key == 'timestamp_offset|0.5|alignment|minimal|1'
    assert grid_from_lists(**{**TINY, 'seeds': [1, 2, 2]}).tasks() == tasks  # repeats collapse
    assert grid_from_lists(**{**TINY, 'seeds': [1, 3]}).fingerprint() != grid.fingerprint()


def test_sizes_scale_the_scaling_parameters_and_keep_the_shaping_ones():
    oscillation = scaled_params('los_oscillation', 3.0)
    assert oscillation == {'amplitude_arcsec': 15.0}  # period and phase shape it (docs/effects.md: 5" default)
    assert scaled_params('gyro_scale_factor', 0.5) == {'el_ppm': 200.0, 'xel_ppm': 200.0, 'los_ppm': 200.0}
    assert scaled_params('vibration_lines', 2.0)['amplitudes_arcsec_per_s'] == [0.1, 0.1]
    assert reference_param('timestamp_offset') == ('offset_s', 1.0)


def test_the_hidden_truth_is_the_nominal_truth_plus_the_effect():
    grid = grid_from_lists(**TINY)
    truth = parse_effect_config(hidden_truth_text(grid.truth, 'timestamp_offset', 2.0))
    assert truth.effects['timestamp_offset']['offset_s'] == 2.0
    assert set(truth.effects) == set(grid.truth.effects) | {'timestamp_offset'}
    assert truth.effects['gyro_misalignment'] == grid.truth.effects['gyro_misalignment']


def test_a_grid_file_gives_the_same_grid(tmp_path):
    path = tmp_path / 'grid.yaml'
    path.write_text('effects: [timestamp_offset, imager_rotation_of_field]\nsizes: [0.5, 2]\n'
                    'campaigns: [alignment:minimal]\nseeds: 2\n')
    assert grid_from_file(path).fingerprint() == grid_from_lists(**TINY).fingerprint()


def test_a_grid_files_model_and_truth_are_read_from_its_folder(tmp_path, monkeypatch):
    # Written beside the grid file and named by their names: found wherever the atlas runs (they were read from the
    # current folder, where a file of that name is another model or none).
    folder = tmp_path / 'study'
    folder.mkdir()
    (folder / 'my-model.yaml').write_text((REPO / 'config' / 'model' / 'nominal.yaml').read_text())
    (folder / 'my-truth.yaml').write_text((REPO / 'config' / 'truth' / 'nominal.yaml').read_text())
    path = folder / 'grid.yaml'
    path.write_text('effects: [timestamp_offset, imager_rotation_of_field]\nsizes: [0.5, 2]\n'
                    'campaigns: [alignment:minimal]\nseeds: 2\nmodel: my-model.yaml\ntruth: my-truth.yaml\n')
    monkeypatch.chdir(tmp_path)
    grid = grid_from_file(path)
    assert grid.model.source == str(folder / 'my-model.yaml') and grid.truth.source == str(folder / 'my-truth.yaml')


# --- bad input ----------------------------------------------------------------------------------------------------

@pytest.mark.parametrize('change, message', [
    ({'effects': ['timestamp_ofset']}, "unknown effect 'timestamp_ofset'; did you mean timestamp_offset"),
    ({'effects': []}, 'the atlas grid is empty: no effects given'),
    ({'seeds': []}, 'the atlas grid is empty: no seeds given'),
    ({'effects': ['gyro_bias']}, "'gyro_bias' is a term of the model"),
    ({'effects': ['seeing']}, "'seeing' is a noise process"),
    ({'sizes': [-1]}, 'must be finite and >= 0'),
    ({'sizes': ['big']}, "size 'big' is not a number"),
    ({'campaigns': ['alignment:tiny']}, "no variant 'tiny'"),
    ({'campaigns': ['gyro-stability']}, 'not read by sofia compare'),
    ({'campaigns': ['polar']}, "unknown campaign 'polar'"),
    ({'sizes': [1e9]}, 'timestamp_offset'),  # the hidden truth outside the parameter's range
    ({'candidates': []}, 'candidates names no effect; leave it out'),  # it ranked the whole catalogue
])
def test_bad_grids_are_one_line(change, message):
    with pytest.raises(ConfigError, match=message):
        grid_from_lists(**{**TINY, **change})


def test_an_unknown_effect_is_its_own_error():
    with pytest.raises(UnknownEffectError):
        grid_from_lists(**{**TINY, 'effects': ['no_such_effect']})


@pytest.mark.parametrize('text, message', [
    ('effects: []\nsizes: [1]\ncampaigns: [alignment]\nseeds: 1\n', 'grid.yaml: the atlas grid is empty: no effects'),
    ('effects: [timestamp_offset]\nsizes: [1]\ncampaigns: [alignment]\nseed: 1\n', r"unknown key\(s\) seed"),
    ('- a list\n', 'a grid file is a mapping'),
    ('effects: timestamp_offset\n', 'effects must be a list'),
])
def test_bad_grid_files_are_one_line(tmp_path, text, message):
    path = tmp_path / 'grid.yaml'
    path.write_text(text)
    with pytest.raises(ConfigError, match=message):
        grid_from_file(path)


def _cli(argv, capsys):
    code = main(['atlas', *argv])
    captured = capsys.readouterr()
    return code, captured.err.strip().splitlines()


@pytest.mark.parametrize('argv, message', [
    (['--effects', 'timestamp_ofset'], "unknown effect 'timestamp_ofset'"),
    (['--effects', ''], 'the atlas grid is empty'),
    (['--seeds', 'x'], "--seeds 'x'"),
    (['--grid', 'g.yaml', '--seeds', '3'], '--grid and --campaigns both given'),
    (['--scheduler', 'localhost'], "--scheduler 'localhost' is not a scheduler address"),
    (['--serial', '--workers', '2'], '--workers sizes the local cluster'),
])
def test_bad_commands_exit_2_with_one_line_and_write_nothing(tmp_path, capsys, argv, message):
    out = tmp_path / 'atlas'
    code, lines = _cli(['--out', str(out), '--campaigns', 'alignment:minimal', *argv], capsys)
    assert code == 2 and len(lines) == 1 and message in lines[0]
    assert not out.exists()


def _free_port():
    with socket.socket() as probe:
        probe.bind(('127.0.0.1', 0))
        return probe.getsockname()[1]


def test_an_unreachable_scheduler_is_one_line_naming_it_within_the_timeout(tmp_path, capsys):
    address = f'tcp://127.0.0.1:{_free_port()}'
    started = time.monotonic()
    code, lines = _cli(['--out', str(tmp_path / 'atlas'), '--effects', 'timestamp_offset', '--sizes', '1',
                        '--campaigns', 'alignment:minimal', '--seeds', '1', '--scheduler', address,
                        '--connect-timeout-s', '2'], capsys)
    assert time.monotonic() - started < 20.0
    assert code == 2 and len(lines) == 1 and f'cannot reach the Dask scheduler at {address} within 2 s' in lines[0]
    assert not (tmp_path / 'atlas').exists()
    with pytest.raises(SchedulerUnreachableError, match='127.0.0.1'):
        with dask_client(address, connect_timeout_s=0.5):
            pass


def test_scheduler_addresses():
    assert checked_scheduler_address('tcp://10.0.0.5:8786') == 'tcp://10.0.0.5:8786'
    with pytest.raises(ConfigError, match='give tcp://HOST:PORT'):
        checked_scheduler_address('10.0.0.5:8786')


# --- the store ----------------------------------------------------------------------------------------------------

def test_rows_land_in_a_parquet_table_once_per_key(tmp_path):
    grid = grid_from_lists(**TINY)
    store = ResultStore(tmp_path / 'table', grid.describe(), flush_s=0.0)
    assert not (tmp_path / 'table').exists()  # nothing written before the first row
    assert store.append(_row(seed=1, wall_s=1.0)) and store.append(_row(seed=2, error='FitError: x'))
    assert not store.append(_row(seed=1))  # a key held is never stored twice
    store.compact()
    table = pq.read_table(tmp_path / 'table')
    assert sorted(table.column('seed').to_pylist()) == [1, 2]
    assert table.schema.metadata[b'sofia_atlas_grid'] == grid.fingerprint().encode()
    reopened = ResultStore(tmp_path / 'table', grid.describe())
    assert reopened.finished_keys() == {_row(seed=1)['key'], _row(seed=2)['key']}


def test_a_table_of_another_grid_is_refused(tmp_path, capsys):
    store = ResultStore(tmp_path / 'atlas' / 'table', grid_from_lists(**TINY).describe(), flush_s=0.0)
    store.append(_row())
    other = grid_from_lists(**{**TINY, 'seeds': [1, 2, 3]})
    with pytest.raises(ConfigError, match='holds the results of a different grid'):
        ResultStore(tmp_path / 'atlas' / 'table', other.describe())
    code, lines = _cli(['--out', str(tmp_path / 'atlas'), '--effects', 'timestamp_offset,imager_rotation_of_field',
                        '--sizes', '0.5,2', '--campaigns', 'alignment:minimal', '--seeds', '3', '--serial'], capsys)
    assert code == 2 and len(lines) == 1 and 'different grid' in lines[0]
    (tmp_path / 'file').write_text('x')
    with pytest.raises(ConfigError, match='is a file'):
        ResultStore(tmp_path / 'file' / 'table', other.describe())


# --- the statistics -----------------------------------------------------------------------------------------------

def test_detection_intervals_are_clopper_pearson():
    rows = [_row(seed=seed, detected=seed <= 3) for seed in range(1, 11)]
    (point,) = detection_curves(rows + [_row(seed=99, error='KilledWorker: x')])  # failed rows count nowhere
    assert (point.trials, point.detections, point.probability) == (10, 3, 0.3)
    # the exact interval from the beta quantiles (Clopper and Pearson 1934), independent of binomtest
    assert point.low == pytest.approx(beta.ppf(0.025, 3, 8), rel=1e-9)
    assert point.high == pytest.approx(beta.ppf(0.975, 4, 7), rel=1e-9)


def test_detectable_sizes_interpolate_the_first_crossing():
    def point(size, probability):
        return DetectionPoint('e', 'alignment:full', size, 10, round(10 * probability), probability, 0.0, 1.0)

    found = {(f.level, f.bound): f.size for f in detectable_sizes([point(0, 0.0), point(1, 0.4), point(2, 1.0)])}
    assert found == {(0.5, '='): pytest.approx(1 + 0.1 / 0.6), (0.9, '='): pytest.approx(1 + 0.5 / 0.6)}
    never = detectable_sizes([point(1, 0.2), point(2, 0.6)])
    assert [(f.level, f.bound, f.size) for f in never] == [(0.5, '=', pytest.approx(1.75)), (0.9, '>', 2)]
    at_once = detectable_sizes([point(1, 1.0)])
    assert [f.bound for f in at_once] == ['<=', '<=']


def test_the_calibration_of_sigmas_finds_honest_and_optimistic_sigmas():
    rng = np.random.default_rng(7)
    honest = [_row(seed=i, size=1.0, param='offset_s', true_value=1.0, fitted_value=1.0 + 0.01 * rng.standard_normal(),
                   fitted_sigma=0.01) for i in range(400)]
    optimistic = [_row(seed=i, size=2.0, param='offset_s', true_value=2.0, fitted_value=2.05 + 0.03 * rng.standard_normal(),
                       fitted_sigma=0.01) for i in range(400)]
    found = {c.size: c for c in fit_calibration(honest + optimistic)}
    assert found[1.0].pull_std == pytest.approx(1.0, abs=0.1) and abs(found[1.0].pull_mean) < 0.15
    assert found[2.0].bias == pytest.approx(0.05, abs=0.005) and found[2.0].pull_std == pytest.approx(3.0, abs=0.3)
    assert found[2.0].scatter == pytest.approx(0.03, abs=0.003) and found[2.0].median_sigma == 0.01


def test_confusions_count_other_top_candidates_and_degenerate_partners():
    rows = [_row(seed=1, detected=True, top_candidate='timestamp_offset', top_delta_bic=50.0),
            _row(seed=2, top_candidate='imager_scale_error', top_delta_bic=30.0, degenerate_with='imager_scale_error'),
            _row(seed=3, top_candidate='imager_scale_error', top_delta_bic=2.0),  # not significant: nothing named
            _row(seed=4, size=0.0, top_candidate='imager_scale_error', top_delta_bic=30.0)]  # control: not counted
    found = {(c.other, c.kind): (c.count, c.trials) for c in confusions(rows)}
    assert found == {('imager_scale_error', 'top candidate'): (1, 3), ('imager_scale_error', 'degenerate'): (1, 3)}


def test_table_6_5_from_eqs_3_32_3_34_3_37_matches_the_printed_table():
    rows = [_row(seed=s, size=0.0, variant=variant, measurements=n, misalignment_el_arcsec=1.0,
                 misalignment_xel_arcsec=-1.0, misalignment_los_arcsec=60.0, predicted_sigma_el_arcsec=1.5,
                 predicted_sigma_los_arcsec=70.0)
            for s in (1, 2) for variant, n in (('one', 1), ('full', 18))]
    rows.append(_row(seed=9, size=2.0, measurements=18, misalignment_el_arcsec=99.0, misalignment_xel_arcsec=0.0,
                     misalignment_los_arcsec=0.0, predicted_sigma_el_arcsec=1.0, predicted_sigma_los_arcsec=1.0))
    table, which = table_6_5_slice(rows)
    assert which == 'control runs (size 0)' and [r.measurements for r in table] == [1, 18]
    for row in table:
        sigma_r_arcsec, sigma_beta_arcmin = TABLE_6_5[row.measurements]
        assert row.thesis_sigma_r_arcsec == pytest.approx(sigma_r_arcsec, abs=0.05)
        assert row.thesis_sigma_beta_arcsec / 60.0 == pytest.approx(sigma_beta_arcmin, abs=0.05)
        assert (row.runs, row.tilt_rms_arcsec, row.los_rms_arcsec) == (2, 1.0, 60.0)


# --- the output ---------------------------------------------------------------------------------------------------

def test_the_text_table_fits_a_screen_and_the_page_has_its_plots(tmp_path):
    rng = np.random.default_rng(1)
    rows = []
    for effect in ('timestamp_offset', 'imager_rotation_of_field', 'gyro_scale_factor'):
        for size in (0.0, 0.5, 1.0, 2.0):
            for seed in range(1, 6):
                rows.append(_row(effect=effect, size=size, seed=seed, detected=bool(rng.random() < size / 2),
                                 param='p', true_value=size, fitted_value=size + 0.1 * rng.standard_normal(),
                                 fitted_sigma=0.1, measurements=6, misalignment_el_arcsec=1.0,
                                 misalignment_xel_arcsec=1.0, misalignment_los_arcsec=50.0,
                                 predicted_sigma_el_arcsec=1.6, predicted_sigma_los_arcsec=70.0,
                                 top_candidate='imager_scale_error', top_delta_bic=10.0))
    summary = summarize(rows)
    text = text_table(summary)
    assert len(text.splitlines()) <= 25 and max(map(len, text.splitlines())) <= 120
    assert 'Table 6.5 slice' in text and 'gyro_scale_factor' in text
    page = write_html(summary, tmp_path / 'report', 'test')
    assert (tmp_path / 'report' / 'detection-0.png').stat().st_size > 1000
    assert (tmp_path / 'report' / 'table-6-5.png').stat().st_size > 1000
    assert 'Clopper-Pearson' in page.read_text()


def test_the_progress_line_says_done_failed_running_eta_and_the_dashboard():
    stream = io.StringIO()
    progress = Progress(4, stream, 'http://127.0.0.1:8787/status')
    progress.finished(_row(), running=2)
    progress.finished(_row(error='x'), running=1)
    last = stream.getvalue().splitlines()[-1]
    assert last.startswith('atlas: 2/4 done, 1 failed, 1 running, 1 waiting;') and 'ETA 0:' in last
    assert last.endswith('dashboard http://127.0.0.1:8787/status')


def test_a_plug_in_effect_is_a_grid_axis_like_any_other(tmp_path):
    """The example plug-in (README) passes the grid; the run then stops at the unreachable scheduler."""
    root = Path(__file__).resolve().parent.parent
    env = {**os.environ, 'SOFIA_EFFECT_MODULES': 'ffi_field_flexure', 'PYTHONPATH': str(root / 'examples/effects')}
    address = f'tcp://127.0.0.1:{_free_port()}'
    done = subprocess.run([sys.executable, '-m', 'sofia_ros.cli', 'atlas', '--out', str(tmp_path / 'atlas'),
                           '--effects', 'ffi_field_flexure', '--sizes', '0.5,1', '--campaigns', 'alignment:minimal',
                           '--seeds', '1', '--scheduler', address, '--connect-timeout-s', '1'],
                          cwd=root, env=env, capture_output=True, text=True, timeout=120)
    assert done.returncode == 2 and f'cannot reach the Dask scheduler at {address}' in done.stderr
    assert done.stdout.startswith('atlas: 2 tasks (1 effects x 2 sizes')
