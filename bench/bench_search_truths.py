"""Benchmark: `sofia compare --search` on many truths with several effects hidden at once (issue 25).

Each truth is the nominal truth plus k effects drawn (seeded) from the effects a reduced alignment
campaign sees (the atlas' VISIBLE_EFFECTS), at their thesis defaults, or with --sizes each at a size drawn
(seeded by the truth's seed) from a list of multiples of its default (the atlas' scaled_params: the scaling
parameters multiplied, the shaping ones kept); the controls hide none. Each is
recorded as the reduced alignment of the tests (2 repetitions, 1 verification; direct mode) and
searched from config/model/nominal.yaml, in worker processes. The draws and the score are the atlas'
own (sofia_ros.atlas.grid.draw_truths, sofia_ros.atlas.scoring: exact, equivalent up to the stated
competitors, equivalent models or absorbed effects, extra, missed; a control is exact when it ends
explained with nothing added); `sofia atlas` runs the same on Dask (bench/bench_multi_effect_atlas.py).
Printed: one row per truth, then the success rate per k, the pairs most often confused, and the wall
time per search.

Run: .venv/bin/python bench/bench_search_truths.py [--truths N] [--controls M] [--k 2,3] [--workers W] [--seed S]
                                                 [--sizes 1,3]
The figures are written to bench/results/search_truths.json (date, commit, load, machine), with --sizes to
bench/results/search_truths_sizes_<sizes>.json.
"""

from __future__ import annotations

import argparse
import collections
import datetime as dt
import json
import os
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

from sofia_ros.atlas.grid import VISIBLE_EFFECTS, draw_truths, scaled_params  # noqa: E402
from sofia_ros.atlas.scoring import (SUCCESSES, confused_pairs, score_truth, stated_competitors,  # noqa: E402
                                     stated_pairs)
from sofia_ros.campaigns.alignment import run_alignment  # noqa: E402
from sofia_ros.compare.observations import read_observations  # noqa: E402
from sofia_ros.compare.run import compare_observations  # noqa: E402
from sofia_ros.compare.search import search_model  # noqa: E402
from sofia_ros.config import load_effect_config, parse_effect_config  # noqa: E402
from sofia_ros.effects import resolve_params  # noqa: E402
from sofia_ros.errors import ConfigError  # noqa: E402
from sofia_ros.sim.calibration import AlignmentPlan  # noqa: E402
from results_file import machine_description  # noqa: E402

NOMINAL_MODEL = ROOT / 'config' / 'model' / 'nominal.yaml'


def _truths(count, controls, ks, seed):
    return draw_truths(VISIBLE_EFFECTS['alignment'], count, tuple(ks), seed) + [()] * controls


def _drawn_sizes(hidden, choices, seed):
    """A size per hidden effect, drawn from the choices its parameters' ranges allow (an imager scale error of 3x
    its 5 % default is beyond them)."""
    rng = np.random.default_rng(seed)
    sizes = []
    for name in hidden:
        allowed = []
        for size in choices:
            try:
                resolve_params(name, scaled_params(name, size), within_ranges=True)
            except ConfigError:
                continue
            allowed.append(size)
        sizes.append(float(rng.choice(allowed)) if allowed else 1.0)
    return tuple(sizes)


def run_one(job):
    """Record one truth, search it; a row."""
    index, hidden, seed, sizes = job
    document = yaml.safe_load((ROOT / 'config' / 'truth' / 'nominal.yaml').read_text())
    for name, size in zip(hidden, sizes):
        document['effects'][name] = scaled_params(name, size) if size != 1.0 else {}
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
    competing = stated_competitors(result.document)
    outcome = score_truth(hidden, added, removed, status, stated_pairs(competing, equivalents), absorbed)
    return {'index': index, 'hidden': list(hidden), 'sizes': list(sizes), 'seed': seed, 'added': added,
            'removed': removed,
            'status': status, 'rounds': len(rounds), 'equivalent': equivalents, 'competing': competing,
            'absorbed': absorbed, 'outcome': outcome,
            'record_s': round(recorded - started, 1), 'search_s': round(searched - recorded, 1)}


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--truths', type=int, default=60)
    parser.add_argument('--controls', type=int, default=20)
    parser.add_argument('--k', default='2,3', help='effects hidden per truth, cycled (default 2,3)')
    parser.add_argument('--workers', type=int, default=2)
    parser.add_argument('--seed', type=int, default=2025)
    parser.add_argument('--sizes', default='1', help='multiples of each hidden effect\'s default to draw from '
                        '(default 1: the defaults)')
    args = parser.parse_args()
    ks = [int(value) for value in args.k.split(',')]
    truths = _truths(args.truths, args.controls, ks, args.seed)
    size_choices = [float(value) for value in args.sizes.split(',')]
    jobs = [(index, hidden, args.seed + index, _drawn_sizes(hidden, size_choices, args.seed + index))
            for index, hidden in enumerate(truths)]
    started = time.time()
    load_before = os.getloadavg()[0]
    rows = []
    with ProcessPoolExecutor(max_workers=args.workers) as pool:
        for row in pool.map(run_one, jobs):
            rows.append(row)
            hidden = '+'.join(name if size == 1.0 else f'{name}x{size:g}'
                              for name, size in zip(row['hidden'], row['sizes']))
            print(f'{row["index"]:3d} {row["outcome"]:10} hidden {hidden or "(control)":<58} '
                  f'added {"+".join(row["added"]) or "-"}; removed {"+".join(row["removed"]) or "-"}; '
                  f'{row["status"]}; {row["rounds"]} rounds, {row["search_s"]:.0f} s', flush=True)
    by_k = collections.defaultdict(list)
    confused = collections.Counter()
    for row in rows:
        by_k[len(row['hidden'])].append(row['outcome'])
        confused.update(confused_pairs(row['hidden'], row['added']))
    print('success per number of hidden effects (reduced alignment, search from the nominal model):')
    for k in sorted(by_k):
        outcomes = collections.Counter(by_k[k])
        right = sum(outcomes[name] for name in SUCCESSES)
        print(f'  k={k}: {right}/{len(by_k[k])} ({100 * right / len(by_k[k]):.0f} %): {outcomes["exact"]} exactly, '
              f'{outcomes["equivalent"]} up to stated competitors, equivalents or absorbed effects, '
              f'{outcomes["extra"]} with an extra term, {outcomes["missed"]} missed')
    for (name, other), count in confused.most_common(8):
        print(f'  confused: {name} taken for {other} ({count}x)')
    searches = [row['search_s'] for row in rows]
    print(f'  search wall time: median {np.median(searches):.0f} s, max {np.max(searches):.0f} s '
          f'({args.workers} workers; load {load_before:.1f} before)')
    commit = subprocess.run(['git', 'rev-parse', '--short', 'HEAD'], cwd=ROOT, capture_output=True,
                            text=True).stdout.strip()
    results = ROOT / 'bench' / 'results'
    results.mkdir(exist_ok=True)
    name = 'search_truths' if size_choices == [1.0] else ('search_truths_sizes_'
                                                          + '_'.join(f'{size:g}' for size in size_choices))
    (results / f'{name}.json').write_text(json.dumps({
        'date': dt.datetime.now(dt.timezone.utc).isoformat(timespec='seconds'), 'commit': commit,
        'machine': machine_description(), 'load_before': load_before,
        'wall_s': round(time.time() - started, 1), 'arguments': vars(args), 'rows': rows}, indent=1) + '\n')


if __name__ == '__main__':
    main()
