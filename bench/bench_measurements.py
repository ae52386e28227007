"""Benchmark: `sofia compare` of a measurement set of a few hundred rows against the nominal model.

The set is the 2004 star hop (data/thesis-2004/star-hop-2004-09-03.yaml) repeated with every move
shifted by 6-minute steps over two hours of the same night: 16 x 20 = 320 star_distance rows, each
with its own ERFA places. Printed: the wall time of the whole command (reading and validating the
file, the places, the fits, every candidate, the refits, printing), and its parts. Target: <= 2 s.

Run: .venv/bin/python bench/bench_measurements.py
"""

from __future__ import annotations

import datetime as dt
import io
import sys
import tempfile
import time
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from sofia_ros.cli import main  # noqa: E402
from sofia_ros.config import load_effect_config  # noqa: E402
from sofia_ros.measurements.compare import compare_measurement_set  # noqa: E402
from sofia_ros.measurements.validate import load_measurement_set  # noqa: E402

from results_file import Transcript, current_load, write_results  # noqa: E402

#: Every line printed, for bench/results/measurements.txt.
TRANSCRIPT = Transcript()
say = TRANSCRIPT.say

SHIFTS = 20
STEP_S = 360.0


def _shifted(when, seconds):
    return (dt.datetime.fromisoformat(when) + dt.timedelta(seconds=seconds)).isoformat()


def large_set(path):
    """The star hop's 16 moves at 20 epochs: 320 rows."""
    document = yaml.safe_load((ROOT / 'data' / 'thesis-2004' / 'star-hop-2004-09-03.yaml').read_text())
    table = document['tables'][0]
    rows = []
    for shift in range(SHIFTS):
        offset = (shift - SHIFTS // 2) * STEP_S
        for row in table['rows']:
            rows.append([f'{row[0]}+{shift}', row[1], _shifted(row[2], offset), row[3], _shifted(row[4], offset),
                         *row[5:]])
    table['rows'] = rows
    document['night_utc'] = ['2004-09-03T00:30:00+00:00', '2004-09-03T11:30:00+00:00']
    path.write_text(yaml.safe_dump(document, sort_keys=False))
    return len(rows)


def main_bench():
    load_before = current_load()
    with tempfile.TemporaryDirectory() as directory:
        path = Path(directory) / 'large-set.yaml'
        rows = large_set(path)
        started = time.perf_counter()
        out = io.StringIO()
        sys.stdout, saved = out, sys.stdout
        try:
            code = main(['compare', str(path), '--model', str(ROOT / 'config' / 'model' / 'nominal.yaml')])
        finally:
            sys.stdout = saved
        wall = time.perf_counter() - started
        load_started = time.perf_counter()
        measurement_set = load_measurement_set(path)
        load_s = time.perf_counter() - load_started
        result = compare_measurement_set(measurement_set, load_effect_config(ROOT / 'config' / 'model' / 'nominal.yaml'))
    verdict = result.document['verdict']['status']
    best = next(c for c in result.document['candidates'] if c['observable'])
    say(f'sofia compare of a measurement set: {rows} star_distance rows, exit {code}')
    say(f'  wall {wall:.2f} s for the whole command (target <= 2 s); parse and validate {load_s:.2f} s; '
        f'places, fits, candidates and refits {result.document["seconds"]["total"]:.2f} s')
    say(f'  verdict {verdict}; best candidate {best["effect"]} ({best["params"]})')
    write_results('measurements', {
        'rows': rows, 'exit_code': code, 'wall_s': wall, 'parse_and_validate_s': load_s,
        'compare_s': result.document['seconds']['total'], 'verdict': verdict,
        'best_candidate': {'effect': best['effect'], 'params': best['params']},
    }, TRANSCRIPT.lines, load_before=load_before)


if __name__ == '__main__':
    main_bench()
