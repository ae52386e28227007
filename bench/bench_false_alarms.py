"""Benchmark: no false alarm on untouched full-size bags, the long records the test suite cannot afford.

An untouched bag (nominal truth, each seed) compared with the nominal model must be judged
explained: every camera axis and gyro axis at its floor, no structure, consistent terms. The
suite checks reduced campaigns (and a reduced one whose bias wanders 30 times as far); here the
full-size campaigns: the default alignment (31 min) and the 17-observation star hop (97 min), over
which Table 5.1's rate random walk wanders the gyro bias by about 0.003 deg/h. Printed per bag:
the verdict, the largest RMS / floor, the strongest finding (listed from 3 sigma), the fitted
gyro biases with their sigmas, and the comparison's wall time with the load beside it.

Run: .venv/bin/python bench/bench_false_alarms.py [--seeds 1 2] [--campaigns alignment star-hop] [BAG ...]
(bags given are compared as they are; otherwise each campaign and seed is recorded in direct mode
in a temporary directory, about 1 min per alignment and 4 min per star hop on this 2-core machine).
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from sofia_ros.campaigns.registry import CAMPAIGNS  # noqa: E402
from sofia_ros.compare.run import compare_bag  # noqa: E402
from sofia_ros.config import load_effect_config  # noqa: E402

from results_file import Transcript, current_load, write_results  # noqa: E402

#: Every line printed, for bench/results/false_alarms.txt.
TRANSCRIPT = Transcript()
say = TRANSCRIPT.say

TRUTH = ROOT / 'config' / 'truth' / 'nominal.yaml'
MODEL = ROOT / 'config' / 'model' / 'nominal.yaml'
#: The campaigns recorded in this run, with their recording times, for bench/results/false_alarms.json.
RECORDED: list[dict] = []


def _load():
    return f'load average {os.getloadavg()[0]:.2f} on {os.cpu_count()} cores'


def record(campaign, seed, folder):
    """The campaign at full size in direct mode, nominal truth: its bag."""
    bag = Path(folder) / f'{campaign}-seed{seed}'
    started = time.perf_counter()
    CAMPAIGNS[campaign].run(load_effect_config(TRUTH), seed=seed, bag_path=bag, mode='direct')
    record_s = time.perf_counter() - started
    say(f'{campaign} seed {seed} recorded in {record_s:.0f} s ({_load()})')
    RECORDED.append({'campaign': campaign, 'seed': seed, 'record_s': record_s, 'load': current_load()})
    return bag


def judge(bag):
    """Compare the bag with the nominal model and print what a false alarm would show; its figures as a dict."""
    started = time.perf_counter()
    document = compare_bag(bag, load_effect_config(MODEL)).document
    wall_s = time.perf_counter() - started
    verdict = document['verdict']
    worst_name, worst = max(verdict['observables'].items(), key=lambda item: item[1]['ratio'])
    findings = document['signature']['trends'] + document['signature']['periods']
    strongest = max(findings, key=lambda finding: finding['significance_sigma'], default=None)
    listed = ('none listed' if strongest is None else
              f'{strongest["observable"]} {strongest.get("variable") or "period %.4g s" % strongest["period_s"]} '
              f'{strongest["significance_sigma"]:.1f} sigma')
    biases = ', '.join(f'{term["param"]} {term["value"]:+.4f} +- {term["sigma"]:.4f}'
                       for term in document['terms'] if term['effect'] == 'gyro_bias')
    say(f'{bag.name}: {verdict["status"]}; largest RMS/floor {worst["ratio"]:.2f} ({worst_name}); strongest finding '
        f'{listed}; {len(document["consistency"])} inconsistent terms')
    say(f'  {biases} deg/h; compare {wall_s:.1f} s wall ({_load()})')
    if verdict['status'] != 'explained':
        say(f'  FALSE ALARM: {verdict["text"]}')
    return {'bag': bag.name, 'status': verdict['status'], 'explained': verdict['status'] == 'explained',
            'largest_rms_over_floor': worst['ratio'], 'largest_rms_observable': worst_name,
            'strongest_finding': listed, 'inconsistent_terms': len(document['consistency']),
            'gyro_biases_deg_per_h': [{'param': term['param'], 'value': term['value'], 'sigma': term['sigma']}
                                      for term in document['terms'] if term['effect'] == 'gyro_bias'],
            'compare_wall_s': wall_s, 'load': current_load()}


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('bags', nargs='*', type=Path)
    parser.add_argument('--seeds', nargs='+', type=int, default=[1, 2])
    parser.add_argument('--campaigns', nargs='+', default=['alignment', 'star-hop'], choices=['alignment', 'star-hop'])
    arguments = parser.parse_args()
    load_before = current_load()
    with tempfile.TemporaryDirectory(prefix='bench_false_alarms_') as folder:
        bags = arguments.bags or [record(campaign, seed, folder)
                                  for campaign in arguments.campaigns for seed in arguments.seeds]
        judged = [judge(bag) for bag in bags]
    explained = [row['explained'] for row in judged]
    say(f'{sum(explained)} of {len(explained)} untouched bags explained')
    write_results('false_alarms', {'recorded': RECORDED, 'bags': judged, 'explained': sum(explained)},
                  TRANSCRIPT.lines, load_before=load_before)


if __name__ == '__main__':
    main()
