"""`sofia noise` on gyro-stability bags: Table 5.1/5.8 readings, Table 5.7, hidden terms found by the loop (5.2)."""

import numpy as np
import pytest
import yaml

from sofia_ros.campaigns.gyro_stability import run_gyro_stability
from sofia_ros.config import parse_effect_config
from sofia_ros.noise.candidates import model_with_candidate
from sofia_ros.noise.fit import noise_adev
from sofia_ros.noise.run import BIAS_STABILITY_MAX_SIGMA_REL, analyze_record, load_noise_record
from sofia_ros.sensors.gyro_errors import tarf_from_gyrf_dcm
from sofia_ros.sensors.gyro_noise import QUANTIZATION_ARCSEC, rate_ramp_deg_per_h2_to_arcsec_per_s2

AXES = ('el', 'xel', 'los')
# Table 5.1, gyro 003 (2008): N 0.00023 deg/sqrt(h) = 0.0138"/sqrt(s), K 0.252 / 60 deg/h^1.5 (the printed
# value is 60x too large, sensors.gyro_noise); the 2008 rate ramps of gyros 001-003 (gyro_bias_drift
# defaults). Lines: the always-present 0.7 and 1.3 Hz of 5.2.5.
ARW_ARCSEC_PER_SQRT_S = 0.0138
RRW_DEG_PER_H_SQRT_H = 0.0042
RAMP_DEG_PER_H2 = {'el': 0.0008, 'xel': 0.00288, 'los': 0.01224}
NOISE_MODEL = f"""effects:
  gyro_noise: {{arw_deg_per_sqrt_h: 0.00023, rrw_deg_per_h_sqrt_h: {RRW_DEG_PER_H_SQRT_H}}}
  gyro_bias_drift: {{}}
  gyro_misalignment: {{}}
  vibration_lines: {{frequencies_hz: [0.7, 1.3], amplitudes_arcsec_per_s: [0.05, 0.05], axes: [el, xel]}}
"""
# The truth adds the Table 5.7 residual biases; TC-1 adds the 20-minute LOS oscillation of 5.2.4 (5").
HOUR_TRUTH = NOISE_MODEL + '  gyro_bias: {}\n'


def _chi2(document):
    return document['model']['residual']['chi2_per_point']


@pytest.fixture(scope='module')
def hour(tmp_path_factory):
    """One hour of TC-1: three periods of the LOS oscillation, tau up to 1200 s (measured: ~28 s)."""
    bag = tmp_path_factory.mktemp('noise') / 'tc1'
    run_gyro_stability(parse_effect_config(HOUR_TRUTH), case='TC-1', hours=1.0, seed=11, bag_path=bag)
    record = load_noise_record(bag)
    return record, analyze_record(record, model=parse_effect_config(NOISE_MODEL, 'noise.yaml'))


def test_arw_of_every_axis_is_table_5_1s_within_the_4_25_accuracy(hour):
    _, analysis = hour
    for axis in AXES:
        values = analysis.document['axes'][axis]
        assert abs(values['arw_arcsec_per_sqrt_s'] - ARW_ARCSEC_PER_SQRT_S) < 3.0 * values['arw_sigma'], axis
        assert values['arw_sigma'] < 0.005 * ARW_ARCSEC_PER_SQRT_S  # 1 h at 400 Hz: 0.1 %
        refit = analysis.document['model']['arw_refit_arcsec_per_sqrt_s'][axis]
        assert abs(refit - ARW_ARCSEC_PER_SQRT_S) < 3.0 * values['arw_sigma'], axis


def test_bias_stability_is_read_where_the_hour_knows_the_curve(hour):
    # Table 5.8 reads the lowest AV point; here among points known to 25 % (4.25). The truth's composite
    # (4.24) bottoms out near 340 s at 0.0011"/s (Table 5.1, gyro 003 2008: 0.0011 deg/h).
    _, analysis = hour
    for index, axis in enumerate(('el', 'xel')):
        values, curve = analysis.document['axes'][axis], analysis.curves[index]
        truth = noise_adev(curve.tau_s, quantization_arcsec=QUANTIZATION_ARCSEC,
                           arw_arcsec_per_sqrt_s=ARW_ARCSEC_PER_SQRT_S,
                           rrw_arcsec_per_s_sqrt_s=RRW_DEG_PER_H_SQRT_H / 60.0,
                           rate_ramp_arcsec_per_s2=rate_ramp_deg_per_h2_to_arcsec_per_s2(RAMP_DEG_PER_H2[axis]))
        at = int(np.flatnonzero(curve.tau_s == values['bias_stability_tau_s'])[0])
        assert curve.sigma_rel[at] <= BIAS_STABILITY_MAX_SIGMA_REL
        # The value is the truth's curve there within the 4.25 error, and that tau lies on the truth's
        # flat bottom within the same error.
        assert abs(values['bias_stability_arcsec_per_s'] - truth[at]) < 3.0 * values['bias_stability_sigma']
        assert truth[at] < truth.min() * (1.0 + 2.0 * curve.sigma_rel[at])
        assert truth.min() == pytest.approx(0.0011, rel=0.05)
        # An hour cannot show that bottom turning up: 4.26 asks ~5 h for 10 % at 340 s.
        assert not values['bias_stability_resolved']
    # LOS: the 20-minute oscillation lifts the curve from tens of seconds on (5.2.6: "only 50 s for the
    # LOS gyro", Table 5.8 TC-1: 0.0027"/s at 50 s), so the minimum is early, high and resolved.
    los = analysis.document['axes']['los']
    assert los['bias_stability_resolved'] and 10.0 < los['bias_stability_tau_s'] < 100.0
    assert 0.002 < los['bias_stability_arcsec_per_s'] < 0.004


def test_hidden_20_minute_los_oscillation_is_the_top_candidate_with_its_period(hour):
    _, analysis = hour
    top = analysis.document['candidates'][0]
    assert (top['effect'], top['axis'], top['significant'], top['degenerate_with']) == (
        'los_oscillation', 'los', True, [])
    # measured: 1182 +- 92 s, 5.03 +- 0.75"
    assert abs(top['params']['period_s'] - 1200.0) < min(0.1 * 1200.0, 3.0 * top['sigma']['period_s'])
    assert abs(top['params']['amplitude_arcsec'] - 5.0) < 3.0 * top['sigma']['amplitude_arcsec']


def test_adding_the_top_candidate_makes_the_residual_fall(hour):
    record, analysis = hour
    before = analysis.document
    effects = model_with_candidate(parse_effect_config(NOISE_MODEL).effects, before['candidates'][0])
    after = analyze_record(record, model=parse_effect_config(yaml.safe_dump({'effects': effects}))).document
    allan_before, allan_after = before['model']['residual']['allan_rms_ln'], after['model']['residual']['allan_rms_ln']
    assert allan_after['los'] < 0.1 * allan_before['los']  # measured: 0.98 -> 0.018
    assert _chi2(after) < _chi2(before)
    assert not any(candidate['significant'] for candidate in after['candidates'])


@pytest.fixture(scope='module')
def pump(tmp_path_factory):
    """Three minutes of TC-3 (no LOS oscillation) with the main oil pump's 30 Hz line on EL, hidden from the model."""
    truth = ('effects:\n  gyro_noise: {}\n  gyro_misalignment: {}\n  gyro_bias: {}\n  vibration_lines: '
             '{frequencies_hz: [0.7, 30.0], amplitudes_arcsec_per_s: [0.05, 0.15], axes: [el, el]}\n')
    model = parse_effect_config('effects:\n  gyro_noise: {}\n  gyro_misalignment: {}\n  vibration_lines: '
                                '{frequencies_hz: [0.7], amplitudes_arcsec_per_s: [0.05], axes: [el]}\n')
    bag = tmp_path_factory.mktemp('noise') / 'tc3'
    run_gyro_stability(parse_effect_config(truth), case='TC-3', hours=0.05, seed=5, bag_path=bag)
    record = load_noise_record(bag)
    return record, model, analyze_record(record, model=model)


def test_hidden_oil_pump_line_is_the_top_candidate_and_named(pump):
    _, _, analysis = pump
    # Three minutes read tau up to 20 s, all on the ARW slope: no bias stability can be claimed.
    assert not any(analysis.document['axes'][axis]['bias_stability_resolved'] for axis in AXES)
    top = analysis.document['candidates'][0]
    assert (top['effect'], top['axis'], top['source'], top['significant']) == (
        'vibration_lines', 'el', 'main oil pump', True)  # Table 5.5
    bin_hz = 400.0 / 2**14
    assert abs(top['params']['frequency_hz'] - 30.0) < min(bin_hz, 3.0 * top['sigma']['frequency_hz'])
    # measured: 0.161 +- 0.020"/s
    assert abs(top['params']['amplitude_arcsec_per_s'] - 0.15) < 3.0 * top['sigma']['amplitude_arcsec_per_s']


def test_adding_the_line_makes_the_residual_fall_and_leaves_nothing_significant(pump):
    record, model, analysis = pump
    effects = model_with_candidate(model.effects, analysis.document['candidates'][0])
    assert effects['vibration_lines']['axes'] == ['el', 'el']
    after = analyze_record(record, model=parse_effect_config(yaml.safe_dump({'effects': effects}))).document
    before = analysis.document['model']['residual']
    assert after['model']['residual']['psd_rms_ln']['el'] < before['psd_rms_ln']['el']
    assert _chi2(after) < _chi2(analysis.document)
    assert not any(candidate['significant'] for candidate in after['candidates'])


def _mean_rate_sigma_deg_per_h(record_s):
    """1-sigma of a mean rate over a record from ARW and RRW, sqrt(N^2 / T + K^2 T / 3) (4.16, 4.20)."""
    return np.sqrt(0.0132**2 / record_s + (0.00216 / 60.0) ** 2 * record_s / 3.0)  # gyro_noise defaults


def test_earth_rate_table_recovers_the_truths_biases_and_names_the_degeneracy(pump):
    # Truth: the Table 5.7 residual biases (gyro_bias defaults), offsets of the gyros (GYRF); the model
    # knows the misalignment, so the deviations are those biases turned into TARF (eq. 3.20).
    record, model, analysis = pump
    earth = analysis.document['earth_rate_deg_per_h']
    assert earth['misalignment_corrected'] is not None
    biases_tarf = tarf_from_gyrf_dcm(model.effects) @ [-0.0643, 0.1624, -0.0909]
    tolerance = 3.0 * _mean_rate_sigma_deg_per_h(record.rates_arcsec_per_s.shape[0] / 400.0)  # 0.003 deg/h
    for axis, bias in zip(AXES, biases_tarf):
        assert abs(earth['deviation'][axis] - bias) < tolerance, axis
    assert ['heading_error', 'gyro_bias'] in analysis.document['degenerate']


def test_earth_rate_table_recovers_a_heading_error(tmp_path):
    # Truth: the GPS heading 3.2 deg off (heading_error default, Table 5.7), no biases.
    truth = parse_effect_config('effects:\n  gyro_noise: {}\n  gyro_misalignment: {}\n  heading_error: {}\n')
    run_gyro_stability(truth, case='TC-3', hours=0.05, seed=6, bag_path=tmp_path / 'tc3')
    model = parse_effect_config('effects:\n  gyro_misalignment: {}\n')
    earth = analyze_record(load_noise_record(tmp_path / 'tc3'), model=model).document['earth_rate_deg_per_h']
    # 4.1-4.3 change by 0.215 deg/h per degree of heading here: 3 sigma of the means is 0.015 deg.
    assert earth['heading_error_deg'] == pytest.approx(3.2, abs=3.0 * _mean_rate_sigma_deg_per_h(180.0) / 0.215)
    assert max(abs(value) for value in earth['deviation_at_best_fit_heading'].values()) < 0.005


def test_every_10th_sample_gives_the_read_out_arw_after_4_27_and_the_quantization_term(pump):
    # Housekeeping data (4.2.5): 40 Hz of the 400 Hz read-out; lines land on their aliases.
    record, model, analysis = pump
    decimated = analyze_record(record, model=model, decimate=10).document
    assert (decimated['sample_rate_hz'], decimated['decimation']) == (40.0, 10)
    for axis in AXES:
        full, tenth = analysis.document['axes'][axis], decimated['axes'][axis]
        assert abs(tenth['arw_arcsec_per_sqrt_s'] - full['arw_arcsec_per_sqrt_s']) < 3.0 * np.hypot(
            tenth['arw_sigma'], full['arw_sigma']), axis
        assert abs(tenth['arw_arcsec_per_sqrt_s'] - 0.0132) < 3.0 * tenth['arw_sigma'], axis
        assert tenth['arw_sampled_arcsec_per_sqrt_s'] > 3.0 * tenth['arw_arcsec_per_sqrt_s']  # sqrt(10) less SF
    sources = {line['source'] for line in decimated['axes']['el']['lines']}
    assert 'main oil pump' in sources  # 30 Hz seen at 10 Hz
