"""The `sofia noise` command: arguments, tables on stdout, JSON file (DESIGN.md section 6, thesis 5.2)."""

from __future__ import annotations

import json
from pathlib import Path

__all__ = ['add_noise_arguments', 'run_noise']


def add_noise_arguments(parser):
    """Arguments of `sofia noise`."""
    parser.add_argument('bag', help='bag directory of `sofia run gyro-stability`')
    parser.add_argument('--json', help='write the analysis as JSON (DESIGN.md section 6)')


def run_noise(args):
    """`sofia noise`: analyze, optionally write the JSON, print the tables (5.2)."""
    from sofia_ros.analysis.noise_report import AXES, analyze_noise

    document = analyze_noise(args.bag)
    if args.json:
        Path(args.json).write_text(json.dumps(document, indent=2) + '\n')
    earth = document['earth_rate_deg_per_h']
    print(f'{document["case"]}: {document["samples_per_axis"]} samples per axis')
    arw_heading, stability_heading = 'ARW "/sqrt(s)', 'bias stab. "/s'
    print(f'  {"axis":<4} {"mean deg/h":>11} {"theory deg/h":>13} {arw_heading:>16} {stability_heading:>16} '
          f'{"at tau s":>9}')
    for axis in AXES:
        values = document['axes'][axis]
        print(f'  {axis.upper():<4} {earth["measured"][axis]:>11.4f} {earth["theoretical"][axis]:>13.4f} '
              f'{values["arw_arcsec_per_sqrt_s"]:>9.4f}+-{values["arw_sigma"]:<6.4f} '
              f'{values["bias_stability_arcsec_per_s"]:>16.4f} {values["bias_stability_tau_s"]:>9.1f}')
    print(f'  heading {earth["heading_deg"]:.1f} deg; the heading that best fits the means (5.2.4): '
          f'{earth["best_fit_heading_deg"]:.2f} deg (heading error and biases are degenerate on a stationary record)')
    print('  specification (Table 5.8): ARW 0.0180"/sqrt(s), bias stability 0.0030"/s')
    for axis in AXES:
        for line in document['axes'][axis]['lines']:
            print(f'  line {axis.upper():<4} {line["freq_hz"]:8.2f} Hz  {line["amplitude_arcsec_per_s"]:.3f}"/s  '
                  f'{line["source"]}')
    return 0
