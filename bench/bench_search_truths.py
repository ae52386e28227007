"""Benchmark: `sofia compare --search` on many truths with several effects hidden at once (issue 25).

Each truth is the nominal truth plus k effects drawn (seeded) from the effects a reduced alignment
campaign sees (VISIBLE_ON_ALIGNMENT), at their thesis defaults; the controls hide none. Each is
recorded as the reduced alignment of the tests (2 repetitions, 1 verification; direct mode) and
searched from config/model/nominal.yaml, in worker processes. A truth is found when the search
ends `explained` with exactly the hidden effects added; found up to equivalents when every hidden
effect is in the final model, or named equivalent to a term there ("X instead of Y" in its
equivalents), or said absorbed by its terms (the final comparison's `unobservable`), and nothing
else is added that is not so named; a control counts when it ends explained with nothing added. Printed: one row per truth, then the
success rate per k, the pairs most often confused, and the wall time per search.

Run: .venv/bin/python bench/bench_search_truths.py [--truths N] [--controls M] [--k 2,3] [--workers W] [--seed S]
The figures are written to bench/results/search_truths.json (date, commit, load, machine).
"""

from __future__ import annotations

import argparse
import collections
import datetime as dt
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np
import yaml

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from sofia_ros.campaigns.alignment import run_alignment  # noqa: E402
from sofia_ros.compare.observations import read_observations  # noqa: E402
from sofia_ros.compare.run import compare_observations  # noqa: E402
from sofia_ros.compare.search import search_model  # noqa: E402
from sofia_ros.config import load_effect_config, parse_effect_config  # noqa: E402
from sofia_ros.sim.calibration import AlignmentPlan  # noqa: E402

#: Effects the reduced alignment campaign detects alone at their defaults (the atlas' alignment rows).
VISIBLE_ON_ALIGNMENT = ('gyro_scale_factor', 'gyro_axis_swap', 'fpi_internal_flexure', 'imager_boresight_offset',
                        'imager_rotation_of_field', 'imager_scale_error', 'hipo_fiducial_error', 'tracker_drift',
                        'timestamp_offset')
NOMINAL_MODEL = ROOT / 'config' / 'model' / 'nominal.yaml'


def _truths(count, controls, ks, seed):
    rng = np.random.default_rng(seed)
    truths = []
    for index in range(count):
        k = ks[index % len(ks)]
        truths.append(tuple(sorted(str(name) for name in rng.choice(VISIBLE_ON_ALIGNMENT, size=k, replace=False))))
    return truths + [()] * controls


def _equivalent_pairs(equivalents):
    """{(in the model, could stand instead)} from the search's 'X instead of Y' equivalents (X, Y: names joined
    by ' and ')."""
    pairs = set()
    for entry in equivalents:
        text = entry['model'].replace(' (compared in full)', '')
        if ' instead of ' in text:
            others, terms = (part.split(' and ') for part in text.split(' instead of '))
            pairs.update((term, other) for term in terms for other in others)
    return pairs


def judge(hidden, found_added, status, equivalents, absorbed=()):
    """'found' (the hidden effects exactly), 'equivalent' (up to the equivalents the search states, or hidden
    effects the final comparison says its terms absorb), or 'missed' (module docstring)."""
    pairs = _equivalent_pairs(equivalents)
    hidden, added = set(hidden), set(found_added)
    if status != 'explained':
        return 'missed'
    if hidden == added:
        return 'found'
    covered = all(name in added or name in absorbed or any((term, name) in pairs for term in added)
                  for name in hidden)
    clean = all(name in hidden or any((name, truth) in pairs for truth in hidden) for name in added)
    return 'equivalent' if covered and clean else 'missed'


def run_one(job):
    """Record one truth, search it; a row."""
    index, hidden, seed = job
    document = yaml.safe_load((ROOT / 'config' / 'truth' / 'nominal.yaml').read_text())
    for name in hidden:
        document['effects'][name] = {}
    truth = parse_effect_config(yaml.safe_dump(document), 'nominal + ' + '+'.join(hidden))
    model = load_effect_config(NOMINAL_MODEL)
    with tempfile.TemporaryDirectory(prefix='sofia-bench-search-') as work:
        bag = Path(work) / 'bag'
        started = time.perf_counter()
        run_alignment(truth, seed=seed, bag_path=bag, mode='direct',
                      plan=AlignmentPlan(repetitions=2, verification_repetitions=1))
        recorded = time.perf_counter()
        observations = read_observations(bag)
        result, found, rounds, equivalents = search_model(
            observations, model, lambda obs, trial: compare_observations(obs, trial))
        searched = time.perf_counter()
    added = sorted(found.fitted - model.fitted)
    removed = sorted(model.fitted - found.fitted)
    status = result.document['verdict']['status']
    absorbed = sorted(set(hidden) & set(result.document['unobservable']))
    outcome = judge(hidden, added, status, equivalents, absorbed) if not removed else 'missed'
    return {'index': index, 'hidden': list(hidden), 'seed': seed, 'added': added, 'removed': removed,
            'status': status, 'rounds': len(rounds), 'equivalent': equivalents, 'absorbed': absorbed,
            'outcome': outcome,
            'record_s': round(recorded - started, 1), 'search_s': round(searched - recorded, 1)}


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--truths', type=int, default=60)
    parser.add_argument('--controls', type=int, default=20)
    parser.add_argument('--k', default='2,3', help='effects hidden per truth, cycled (default 2,3)')
    parser.add_argument('--workers', type=int, default=2)
    parser.add_argument('--seed', type=int, default=2025)
    args = parser.parse_args()
    ks = [int(value) for value in args.k.split(',')]
    truths = _truths(args.truths, args.controls, ks, args.seed)
    jobs = [(index, hidden, args.seed + index) for index, hidden in enumerate(truths)]
    started = time.time()
    load_before = os.getloadavg()[0]
    rows = []
    with ProcessPoolExecutor(max_workers=args.workers) as pool:
        for row in pool.map(run_one, jobs):
            rows.append(row)
            print(f'{row["index"]:3d} {row["outcome"]:10} hidden {"+".join(row["hidden"]) or "(control)":<58} '
                  f'added {"+".join(row["added"]) or "-"}; removed {"+".join(row["removed"]) or "-"}; '
                  f'{row["status"]}; {row["rounds"]} rounds, {row["search_s"]:.0f} s', flush=True)
    by_k = collections.defaultdict(list)
    confused = collections.Counter()
    for row in rows:
        by_k[len(row['hidden'])].append(row['outcome'])
        for name in set(row['hidden']) - set(row['added']):
            for other in set(row['added']) - set(row['hidden']):
                confused[(name, other)] += 1
    print('success per number of hidden effects (reduced alignment, search from the nominal model):')
    for k in sorted(by_k):
        outcomes = collections.Counter(by_k[k])
        right = outcomes['found'] + outcomes['equivalent']
        print(f'  k={k}: {right}/{len(by_k[k])} ({100 * right / len(by_k[k]):.0f} %): {outcomes["found"]} exactly, '
              f'{outcomes["equivalent"]} up to stated equivalents or absorbed effects, {outcomes["missed"]} missed')
    for (name, other), count in confused.most_common(8):
        print(f'  confused: {name} taken for {other} ({count}x)')
    searches = [row['search_s'] for row in rows]
    print(f'  search wall time: median {np.median(searches):.0f} s, max {np.max(searches):.0f} s '
          f'({args.workers} workers; load {load_before:.1f} before)')
    commit = subprocess.run(['git', 'rev-parse', '--short', 'HEAD'], cwd=ROOT, capture_output=True,
                            text=True).stdout.strip()
    results = ROOT / 'bench' / 'results'
    results.mkdir(exist_ok=True)
    (results / 'search_truths.json').write_text(json.dumps({
        'date': dt.datetime.now(dt.timezone.utc).isoformat(timespec='seconds'), 'commit': commit,
        'machine': f'{platform.machine()}, {os.cpu_count()} cores', 'load_before': load_before,
        'wall_s': round(time.time() - started, 1), 'arguments': vars(args), 'rows': rows}, indent=1) + '\n')


if __name__ == '__main__':
    main()
