"""Benchmark: `sofia noise --report --json --model` on a 4 h TC-1 bag, and its Allan part beside allantools.

The bag is the full TC-1 length of 5.2.1 (5.76 M samples per axis) from config/truth/nominal.yaml;
it is recorded into a temporary directory unless --bag names an existing one. The model is the
nominal gyro noise and mounting without the case's lines, so the loop has lines and the LOS
oscillation to find. Printed: the command's wall time split into reading the bag, the analysis
and the report (target <= 60 s in all), and the overlapping Allan deviation of the analysis
(60 log-spaced taus, 3 axes) against allantools.oadev on the same data and taus.

Run: .venv/bin/python bench/bench_noise.py [--bag bags/tc1]

Recorded on the 2-core target machine on 2026-11-26 at 15:27 UTC, load about 1 (numpy 2.4, scipy 1.17,
matplotlib 3.11, allantools 2024.6):

    sofia noise --model --report --json: exit 0, 15.7 s wall (target <= 60 s)
      split: read bag 3.5 s, analysis 6.8 s (16 candidates ranked), report 3.9 s
      Allan part, 5,760,000 samples x 3 axes, 60 taus: ours 0.52 s, allantools.oadev 3.97 s, 8x;
      largest relative difference 5.7e-12
      top candidates: vibration_lines xel 179.10 Hz (delta BIC 1227); vibration_lines el 179.10 Hz
      (delta BIC 1222); vibration_lines el 1.30 Hz (delta BIC 405)
"""

from __future__ import annotations

import argparse
import shutil
import tempfile
import time
from pathlib import Path

import allantools
import numpy as np

from sofia_ros.analysis.allan import log_spaced_cluster_sizes, overlapping_allan_deviation
from sofia_ros.campaigns.gyro_stability import run_gyro_stability
from sofia_ros.cli import main as sofia
from sofia_ros.config import load_effect_config, parse_effect_config
from sofia_ros.noise.report import write_report
from sofia_ros.noise.run import analyze_record, load_noise_record

from results_file import Transcript, current_load, write_results

REPOSITORY = Path(__file__).resolve().parents[1]
MODEL = 'effects:\n  gyro_noise: {}\n  gyro_misalignment: {}\n'
SAMPLE_RATE_HZ = 400.0
N_TAUS = 60  # as noise_report
#: Every line printed, for bench/results/noise.txt.
TRANSCRIPT = Transcript()
say = TRANSCRIPT.say


def _bag(folder, given, document):
    if given is not None and Path(given).exists():
        return Path(given)
    path = folder / 'tc1'
    truth = load_effect_config(REPOSITORY / 'config/truth/nominal.yaml')
    start = time.perf_counter()
    run_gyro_stability(truth, case='TC-1', hours=4.0, seed=1, bag_path=path)
    document['record_s'] = time.perf_counter() - start
    say(f'recorded a 4 h TC-1 bag in {document["record_s"]:.1f} s')
    return path


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--bag', help='an existing 4 h gyro-stability bag (default: record one)')
    args = parser.parse_args()
    load_before = current_load()
    document = {'bag': args.bag}
    folder = Path(tempfile.mkdtemp(prefix='bench_noise_'))
    try:
        bag = _bag(folder, args.bag, document)
        model_path = folder / 'noise.yaml'
        model_path.write_text(MODEL)

        start = time.perf_counter()
        status = sofia(['noise', str(bag), '--model', str(model_path), '--report', str(folder / 'report'),
                        '--json', str(folder / 'noise.json')])
        command_s = time.perf_counter() - start
        say(f'\nsofia noise --model --report --json: exit {status}, {command_s:.1f} s wall (target <= 60 s)')

        start = time.perf_counter()
        record = load_noise_record(bag)
        read_s = time.perf_counter() - start
        analysis = analyze_record(record, model=parse_effect_config(MODEL))
        analyze_s = time.perf_counter() - start - read_s
        write_report(analysis, folder / 'report_again')
        report_s = time.perf_counter() - start - read_s - analyze_s
        say(f'  split: read bag {read_s:.1f} s, analysis {analyze_s:.1f} s '
            f'({len(analysis.document["candidates"])} candidates ranked), report {report_s:.1f} s')

        noise = analysis.noise_arcsec_per_s
        sizes = log_spaced_cluster_sizes(len(noise), N_TAUS)
        start = time.perf_counter()
        ours = overlapping_allan_deviation(noise, SAMPLE_RATE_HZ, sizes)
        ours_s = time.perf_counter() - start
        start = time.perf_counter()
        theirs = [allantools.oadev(np.ascontiguousarray(noise[:, axis]), rate=SAMPLE_RATE_HZ, data_type='freq',
                                   taus=sizes / SAMPLE_RATE_HZ)[1] for axis in range(3)]
        theirs_s = time.perf_counter() - start
        deviation = max(float(np.max(np.abs(curve.adev / reference - 1.0))) for curve, reference in zip(ours, theirs))
        say(f'  Allan part, {len(noise):,} samples x 3 axes, {sizes.size} taus: ours {ours_s:.2f} s, '
            f'allantools.oadev {theirs_s:.2f} s, {theirs_s / ours_s:.0f}x; largest relative difference {deviation:.1e}')
        top = analysis.document['candidates'][:3]
        say('  top candidates: ' + '; '.join(f'{c["label"]} (delta BIC {c["delta_bic"]:.0f})' for c in top))
        document.update(
            exit_code=status, command_s=command_s, read_s=read_s, analysis_s=analyze_s, report_s=report_s,
            candidates=len(analysis.document['candidates']), samples_per_axis=len(noise), taus=sizes.size,
            allan_ours_s=ours_s, allan_allantools_s=theirs_s, allan_speed_up=theirs_s / ours_s,
            allan_largest_relative_difference=deviation,
            top_candidates=[{'label': c['label'], 'delta_bic': c['delta_bic']} for c in top])
    finally:
        shutil.rmtree(folder)
    write_results('noise', document, TRANSCRIPT.lines, load_before=load_before)


if __name__ == '__main__':
    main()
