"""The `sofia noise` command: arguments, tables on stdout, JSON file, HTML report (docs/noise.md, thesis 5.2)."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from sofia_ros.errors import ConfigError
from sofia_ros.output_files import checked_output_directory, checked_output_file, json_ready, write_text_atomically

__all__ = ['add_noise_arguments', 'run_noise']

_CANDIDATES_SHOWN = 8


def add_noise_arguments(parser: argparse.ArgumentParser) -> None:
    """Arguments of `sofia noise`.

    Args:
        parser: the `sofia noise` subparser.
    """
    parser.add_argument('bag', help='bag directory of `sofia run gyro-stability`')
    parser.add_argument('--json', metavar='OUT', help='write the analysis as JSON (docs/noise.md)')
    parser.add_argument('--report', metavar='DIR',
                        help='write DIR/index.html with PNG plots (Figs. 5.5-5.17); DIR must not exist or be empty')
    parser.add_argument('--model', metavar='N.yaml',
                        help='noise model, an effects file like a truth (gyro_noise, gyro_bias_drift, vibration_lines, '
                             'los_oscillation; gyro_misalignment corrects the Earth-rate means): residual and '
                             'missing terms are ranked against it (default: no effects)')
    parser.add_argument('--decimate', default='1', metavar='K',
                        help='analyze every K-th sample, as housekeeping data recorded below the 400 Hz read-out '
                             '(4.2.5); the ARW is corrected back by 4.27 (default 1)')


def _check_json_target(path):
    target = Path(path)
    if target.is_dir():
        raise ConfigError(f'--json {target} is a directory; give a file name'
                          + ('' if (target / 'metadata.yaml').exists() else f', e.g. {target / "noise.json"}'))
    if not target.parent.is_dir():
        raise ConfigError(f'cannot write --json {target}: give a file in an existing directory')
    return target


def run_noise(args: argparse.Namespace) -> int:
    """`sofia noise`: check every input, analyze, write report and JSON, print the tables (5.2).

    Args:
        args: the parsed arguments of add_noise_arguments.

    Returns:
        The exit code, 0 (every failure raises a SofiaError that sofia_ros.cli turns into one line and exit 2 or 3).

    Raises:
        ConfigError: a --json target in no existing directory, a --report directory in use, or a bad model.
        InvalidArgumentError: a bad --decimate or a record too short.
        BagError: a bag without the topics the analysis reads.
    """
    from sofia_ros.noise.predict import check_noise_model
    from sofia_ros.noise.report import check_report_dir, write_report
    from sofia_ros.noise.run import analyze_record, checked_decimation, load_noise_record
    from sofia_ros.config import load_effect_config

    decimate = checked_decimation(args.decimate)
    model = load_effect_config(args.model) if args.model else None
    if model is not None:
        check_noise_model(model.effects)
    json_target = _check_json_target(args.json) if args.json else None
    inputs = {'the bag': args.bag, 'the model': args.model}
    if json_target is not None:
        # Not into the report's folder either: `--json REPORT/index.html` replaced the page at exit 0.
        checked_output_file('--json', args.json, {**inputs, '--report': args.report})
    if args.report:
        check_report_dir(args.report)
        checked_output_directory('--report', args.report, inputs)
    analysis = analyze_record(load_noise_record(args.bag), model=model, decimate=decimate)
    if args.report:
        write_report(analysis, args.report)
    if json_target is not None:
        text = json.dumps(json_ready(analysis.document), indent=2, allow_nan=False) + '\n'
        write_text_atomically(json_target, text)
    _print_document(analysis.document)
    if args.report:
        print(f'report: {Path(args.report) / "index.html"}')
    return 0


def _print_document(document):
    from sofia_ros.frames import AXES

    print(f'{document["case"]}: {document["description"]}; {document["samples_per_axis"]} samples per axis at '
          f'{document["sample_rate_hz"]:g} Hz ({document["record_s"]:.0f} s)')
    if document['subsystems']:
        print('  TA subsystems (Table 5.2): ' + ', '.join(f'{key} {value}' for key, value in
                                                         document['subsystems'].items()))
    _print_earth_rate(document['earth_rate_deg_per_h'], AXES)
    _print_noise(document, AXES)
    _print_model(document)


def _print_earth_rate(earth, axes):
    print('  Earth rate (Table 5.7 layout), deg/h:       EL         XEL         LOS')
    rows = [('measurement mean (GYRF)', earth['measured'])]
    if earth['misalignment_corrected'] is not None:
        rows.append(('misalignment corrected (TARF)', earth['misalignment_corrected']))
    rows += [(f'theoretical, heading {earth["heading_deg"]:.1f} deg', earth['theoretical']),
             ('  deviation (apparent bias)', earth['deviation']),
             (f'theoretical, heading {earth["best_fit_heading_deg"]:.2f} deg',
              earth['theoretical_at_best_fit_heading']),
             ('  deviation (apparent bias)', earth['deviation_at_best_fit_heading'])]
    for label, row in rows:
        print(f'    {label:<36}' + ''.join(f'{row[axis]:>11.4f}' for axis in axes))
    print(f'    least-squares heading {earth["best_fit_heading_deg"]:.2f} deg ({earth["heading_error_deg"]:+.2f} deg): '
          'heading error and gyro biases are degenerate on a stationary record (5.2.4)')


def _print_noise(document, axes):
    headings = ('axis', 'ARW "/sqrt(s)', 'bias stab. "/s', 'at tau s', 'RRW "/s^1.5', 'max angle "')
    print('  {:<4} {:>18} {:>16} {:>9} {:>20} {:>12}'.format(*headings))
    for axis in axes:
        values = document['axes'][axis]
        resolved = '' if values['bias_stability_resolved'] else '*'
        print(f'  {axis.upper():<4} {values["arw_arcsec_per_sqrt_s"]:>9.5f}+-{values["arw_sigma"]:<7.5f} '
              f'{values["bias_stability_arcsec_per_s"]:>16.5f} {values["bias_stability_tau_s"]:>8.1f}{resolved:1} '
              f'{values["rrw_arcsec_per_s_sqrt_s"]:>10.2e}+-{values["rrw_sigma"]:<8.1e} '
              f'{values["integrated_angle_max_arcsec"]:>12.2f}')
    if document['decimation'] > 1:
        print(f'  every {document["decimation"]}. sample: ARW corrected to 400 Hz by 4.27 less the white quantization '
              '(sampled values in the JSON)')
    if not all(document['axes'][axis]['bias_stability_resolved'] for axis in axes):
        print('  * the curve does not rise significantly after its minimum among the taus known to 25 % (4.25): '
              'an upper bound, the record is too short to resolve the bias stability')
    print('  specification (Table 5.8): ARW 0.0180"/sqrt(s), bias stability 0.0030"/s')
    for axis in axes:
        for line in document['axes'][axis]['lines']:
            print(f'  line {axis.upper():<4} {line["freq_hz"]:8.2f} Hz  {line["amplitude_arcsec_per_s"]:.3f}"/s  '
                  f'{line["source"]}')


def _print_model(document):
    model, residual = document['model'], document['model']['residual']
    effects = ', '.join(model['effects']) or 'no effects'
    print(f'  noise model {model["path"] or "(none)"}: {effects}; ARW refitted per axis '
          + ', '.join(f'{axis.upper()} {value:.5f}' for axis, value in model['arw_refit_arcsec_per_sqrt_s'].items()))
    print(f'  residual: RMS ln root AV {residual["allan_rms_ln"]["all"]:.3f}, '
          f'ln PSD {residual["psd_rms_ln"]["all"]:.3f}, chi^2/point {residual["chi2_per_point"]:.2f}')
    print(f'  missing terms, best first (delta BIC >= 6 significant): {len(document["candidates"])} candidates')
    for candidate in document['candidates'][:_CANDIDATES_SHOWN]:
        params = ', '.join(f'{name} {value:.4g} +- {candidate["sigma"][name]:.2g}'
                           for name, value in candidate['params'].items())
        flags = ('' if candidate['significant'] else ' (not significant)') + (
            f' degenerate with {", ".join(candidate["degenerate_with"])}' if candidate['degenerate_with'] else '')
        source = f' [{candidate["source"]}]' if candidate.get('source') else ''
        print(f'    {candidate["delta_bic"]:>9.1f}  {candidate["label"]}{source}: {params}{flags}')
