"""Benchmark: `sofia compare` where the user works, the Waco 2004 loop of compare and `sofia model` rounds.

The Waco 2004 truth (config/truth/waco-2004.yaml: five hidden effects) is flown once per campaign
(the reduced alignment, seed 7, and the 17-observation star hop, seed 3904, both --direct), then
the user's loop is followed as the README teaches it: `sofia compare BAG --model M --json J`,
then the command the verdict names (`verdict.next.command`: `sofia model add|remove|replace`),
up to --rounds rounds or until the verdict has nothing to do. Each compare runs in its own process
as a user runs it; printed per round: its wall time, its peak memory (the proportional set size of
the command and its --jobs workers together, sampled every 0.25 s), its status, RMS and next step,
and whether it read the bag or the observation cache (the first compare of a bag decodes it, the
later ones read the cache). Beside the loop, the same bag
with the nominal model once more with --no-cache: the decode's share of a compare.

With ``--baseline CHECKOUT`` (another checkout, e.g. ``git worktree add /tmp/base <commit>``) every
round's compare also runs from that checkout on the same model (without the cache, which it may
not know), and the two JSON outputs are checked: the same verdict and next step, every fitted term
within AGREEMENT_SIGMA of its sigma; its wall time is printed beside this checkout's.

With ``--search`` the same bag is searched instead (`sofia compare BAG --model nominal --search --no-cache`, one
command, issue 25): its wall and CPU time, peak memory, rounds and the model found, against issue 25's targets
(SEARCH_TARGET_S); with ``--baseline`` the baseline's search runs right after it, and the two must find the same
model.

The figures are written to bench/results/compare_loop_<campaigns>.{json,txt} (date, commit, load, machine;
search_<campaigns>.{json,txt} with ``--search``).

Run: .venv/bin/python bench/bench_compare_loop.py [--campaigns alignment,star-hop] [--rounds 8] [--seed N] [--baseline DIR]
     [--search]
"""

from __future__ import annotations

import argparse
import datetime as dt
import json
import os
import shutil
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

from sofia_ros.compare.cache import CACHE_DIRECTORY
from results_file import machine_description

ROOT = Path(__file__).resolve().parents[1]
TRUTH = ROOT / 'config' / 'truth' / 'waco-2004.yaml'
MODEL = ROOT / 'config' / 'model' / 'nominal.yaml'
#: The loops of issues 25 and 27: campaign -> (seed, extra `sofia run` options).
LOOPS = {'alignment': (7, ['--variant', 'reduced']), 'star-hop': (3904, [])}
#: Issue 27's targets per compare round: wall seconds and peak memory.
TARGET_S = {'alignment': 4.0, 'star-hop': 15.0}
TARGET_MEMORY_MB = 600.0
#: Issue 25's targets for one `sofia compare --search` from the nominal model: wall seconds.
SEARCH_TARGET_S = {'alignment': 45.0, 'star-hop': 180.0}
#: Fitted values of this checkout and the baseline may differ by this fraction of their sigma (issue 27).
AGREEMENT_SIGMA = 0.01
#: Every line printed, for bench/results/compare_loop_<campaigns>.txt.
PRINTED: list[str] = []


def _say(line: str) -> None:
    PRINTED.append(line)
    print(line, flush=True)


def _sofia(checkout: Path, *arguments: str) -> tuple[subprocess.CompletedProcess, float, float]:
    """`python -m sofia_ros.cli ARGUMENTS` from a checkout: the completed process, its wall s and its peak MB (of all
    its processes together, _tree_pss_mb)."""
    process, wall_s, peak_mb, _ = _sofia_timed(checkout, *arguments)
    return process, wall_s, peak_mb


def _descendants(pid: int) -> list[int]:
    """``pid`` and every process below it (from /proc/<pid>/task/*/children)."""
    found, queue = [], [pid]
    while queue:
        parent = queue.pop()
        found.append(parent)
        for task in Path(f'/proc/{parent}/task').glob('*'):
            try:
                queue += [int(child) for child in (task / 'children').read_text().split()]
            except OSError:
                continue
    return found


def _tree_pss_mb(pid: int) -> float:
    """The proportional set size of ``pid`` and its descendants together, MB: `sofia compare --jobs` forks workers
    that share the parent's pages; their maxrss each counts the shared pages again, their PSS shares them out."""
    total_kb = 0
    for each in _descendants(pid):
        try:
            rollup = Path(f'/proc/{each}/smaps_rollup').read_text()
        except OSError:
            continue
        total_kb += next((int(line.split()[1]) for line in rollup.splitlines() if line.startswith('Pss:')), 0)
    return total_kb / 1024.0


def _sofia_timed(checkout: Path, *arguments: str) -> tuple[subprocess.CompletedProcess, float, float, float]:
    """_sofia, and the child's CPU seconds (user + system, its workers' included)."""
    environment = {**os.environ, 'PYTHONPATH': str(checkout)}
    with tempfile.TemporaryFile('w+') as stdout, tempfile.TemporaryFile('w+') as stderr:
        started = time.perf_counter()
        process = subprocess.Popen([sys.executable, '-m', 'sofia_ros.cli', *arguments], cwd=checkout,
                                   env=environment, stdout=stdout, stderr=stderr, text=True)
        peak_mb = [0.0]
        finished = threading.Event()

        def sample() -> None:
            while not finished.wait(0.25):
                peak_mb[0] = max(peak_mb[0], _tree_pss_mb(process.pid))

        sampler = threading.Thread(target=sample, daemon=True)
        sampler.start()
        # wait4 reaps this child alone and gives its resource usage with that of the children it waited for.
        _, status, usage = os.wait4(process.pid, 0)
        finished.set()
        sampler.join()
        wall_s = time.perf_counter() - started
        process.returncode = os.waitstatus_to_exitcode(status)
        stdout.seek(0)
        stderr.seek(0)
        completed = subprocess.CompletedProcess(process.args, process.returncode, stdout.read(), stderr.read())
    # A command too short for a sample: its own maxrss (KiB on Linux).
    return completed, wall_s, peak_mb[0] or usage.ru_maxrss / 1024.0, usage.ru_utime + usage.ru_stime


def _checked(process: subprocess.CompletedProcess, what: str) -> subprocess.CompletedProcess:
    if process.returncode != 0:
        raise SystemExit(f'{what} failed (exit {process.returncode}): {process.stderr.strip()[-400:]}')
    return process


def _agreement(document: dict, baseline: dict) -> tuple[bool, float]:
    """The same verdict status and next step, and the largest |difference| / sigma of the fitted terms."""
    same = (document['verdict']['status'] == baseline['verdict']['status']
            and (document['verdict'].get('next') or {}).get('effect') == (baseline['verdict'].get('next') or {}).get('effect'))
    worst = 0.0
    for term, other in zip(document['terms'], baseline['terms']):
        if (term['effect'], term['param']) != (other['effect'], other['param']):
            return False, float('inf')
        if term['sigma'] is not None and term['sigma'] > 0:  # null: a parameter the data leave unconstrained
            worst = max(worst, abs(term['value'] - other['value']) / term['sigma'])
    return same, worst


def _flown(campaign: str, seed: int, work: Path) -> tuple[Path, float]:
    """The Waco 2004 truth flown on one campaign: the bag and the run's wall seconds."""
    bag = work / f'waco-{campaign}'
    _, run_s, _ = _sofia(ROOT, 'run', campaign, '--truth', str(TRUTH), '--seed', str(seed), '--bag', str(bag),
                         '--direct', *LOOPS[campaign][1])
    if not (bag / 'metadata.yaml').exists():
        raise SystemExit(f'sofia run {campaign} wrote no bag in {bag}')
    return bag, run_s


def _search(checkout: Path, bag: Path, output: Path) -> dict:
    """One `sofia compare --search --no-cache` from the nominal model: its times, rounds and the model found."""
    process, wall_s, peak_mb, cpu_s = _sofia_timed(checkout, 'compare', str(bag), '--model', str(MODEL), '--search',
                                                   '--no-cache', '--quiet', '--json', str(output))
    _checked(process, f'sofia compare --search from {checkout}')
    search = json.loads(output.read_text())['search']
    return {'wall_s': round(wall_s, 1), 'cpu_s': round(cpu_s, 1), 'peak_mb': round(peak_mb),
            'rounds': len(search['rounds']), 'found': search['added'], 'status': search['status'],
            'equivalent': [entry['model'] for entry in search['equivalent']], 'ends': search['rounds'][-1]['ends']}


def run_search(campaign: str, seed: int, work: Path, baseline: Path | None) -> dict:
    """Fly the Waco 2004 truth on one campaign and search it from the nominal model (and from the baseline)."""
    bag, run_s = _flown(campaign, seed, work)
    row = {'campaign': campaign, 'seed': seed, 'run_s': round(run_s, 1), 'target_s': SEARCH_TARGET_S[campaign],
           'search': _search(ROOT, bag, work / f'{campaign}-search.json')}
    found = row['search']
    _say(f'  {campaign} --search: {found["wall_s"]:.1f} s wall, {found["cpu_s"]:.1f} CPU-s, {found["peak_mb"]} MB, '
         f'{found["rounds"]} rounds (target <= {SEARCH_TARGET_S[campaign]:.0f} s): {found["status"]}, found '
         f'{", ".join(found["found"]) or "nothing"}; equivalent: {"; ".join(found["equivalent"]) or "none"}; '
         f'{found["ends"]}')
    if baseline is not None:
        old = row['baseline_search'] = _search(baseline, bag, work / f'{campaign}-search-baseline.json')
        row['same_model'] = all(old[key] == found[key] for key in ('found', 'status', 'equivalent'))
        _say(f'  {campaign} --search from the baseline: {old["wall_s"]:.1f} s wall, {old["cpu_s"]:.1f} CPU-s, '
             f'{old["peak_mb"]} MB, {old["rounds"]} rounds; CPU ratio {found["cpu_s"] / old["cpu_s"]:.2f}, '
             f'the same model and equivalents found: {row["same_model"]}')
    return row


def run_loop(campaign: str, seed: int, rounds: int, work: Path, baseline: Path | None) -> dict:
    """Fly the Waco 2004 truth on one campaign and follow the advice loop; the rows of every round."""
    bag, run_s = _flown(campaign, seed, work)
    model = work / f'model-{campaign}.yaml'
    shutil.copy(MODEL, model)
    # The baseline reads a copy: code of another reader version would replace this code's observation cache
    # (one per bag) each round, and both would decode the bag every time.
    baseline_bag = None
    if baseline is not None:
        baseline_bag = work / f'{bag.name}-baseline'
        shutil.rmtree(baseline_bag, ignore_errors=True)
        shutil.copytree(bag, baseline_bag, ignore=shutil.ignore_patterns(CACHE_DIRECTORY))
    rows = []
    for number in range(1, rounds + 1):
        output = work / f'{campaign}-{number}.json'
        process, wall_s, peak_mb = _sofia(ROOT, 'compare', str(bag), '--model', str(model), '--json', str(output))
        _checked(process, f'compare round {number}')
        document = json.loads(output.read_text())
        next_step = document['verdict'].get('next') or {}
        row = {'round': number, 'model': [entry['term'] for entry in document['ledger'][1:]], 'wall_s': round(wall_s, 2), 'peak_mb': round(peak_mb), 'cache': 'read' if number > 1 else 'written',
               'status': document['verdict']['status'], 'rms_arcsec': document['residual_rms_arcsec']['total'],
               'next': next_step.get('command') or next_step.get('action')}
        if baseline is not None:
            old_output = work / f'{campaign}-{number}-baseline.json'
            old, old_wall_s, old_peak_mb = _sofia(baseline, 'compare', str(baseline_bag), '--model', str(model),
                                                  '--json', str(old_output))
            _checked(old, f'baseline compare round {number}')
            same, worst = _agreement(document, json.loads(old_output.read_text()))
            row.update(baseline_wall_s=round(old_wall_s, 2), baseline_peak_mb=round(old_peak_mb), same_verdict=same,
                       worst_sigma=worst)
        rows.append(row)
        _say(f'  {campaign} round {number}: {wall_s:6.1f} s {peak_mb:6.0f} MB ({row["cache"]} cache) '
              f'{row["status"]:<15} RMS {row["rms_arcsec"]:.3f}"  next: {row["next"]}'
              + (f'  | baseline {row["baseline_wall_s"]:.1f} s {row["baseline_peak_mb"]} MB, '
                 f'same verdict {row["same_verdict"]}, '
                 f'worst {row["worst_sigma"]:.2g} sigma' if baseline is not None else ''))
        command = next_step.get('command') or ''
        if next_step.get('action') not in ('add', 'remove', 'replace') or not command.startswith('sofia model '):
            break
        _checked(_sofia(ROOT, *command.split()[1:])[0], command)
    process, cold_s, cold_mb = _sofia(ROOT, 'compare', str(bag), '--model', str(MODEL), '--no-cache', '--quiet')
    _checked(process, 'compare --no-cache')
    process, warm_s, _ = _sofia(ROOT, 'compare', str(bag), '--model', str(MODEL), '--quiet')
    _checked(process, 'compare from the cache')
    _say(f'  {campaign}: the nominal model again, without the cache {cold_s:.1f} s ({cold_mb:.0f} MB), '
          f'from the cache {warm_s:.1f} s (ratio {warm_s / cold_s:.2f}); the run itself took {run_s:.0f} s')
    return {'campaign': campaign, 'seed': seed, 'run_s': round(run_s, 1), 'rounds': rows,
            'loop_compare_s': round(sum(row['wall_s'] for row in rows), 1),
            'nominal_without_cache_s': round(cold_s, 2), 'nominal_from_cache_s': round(warm_s, 2)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--campaigns', default='alignment,star-hop')
    parser.add_argument('--rounds', type=int, default=8)
    parser.add_argument('--baseline', type=Path, help='another checkout to run every round beside this one')
    parser.add_argument('--seed', type=int, help="the campaigns' seed (default: each loop's own, LOOPS)")
    parser.add_argument('--search', action='store_true',
                        help='time one `sofia compare --search` per campaign instead of the loop (issue 25)')
    args = parser.parse_args()
    load_before = os.getloadavg()[0]
    started = time.time()
    loops = []
    with tempfile.TemporaryDirectory(prefix='sofia-bench-loop-') as work:
        for campaign in args.campaigns.split(','):
            seed = LOOPS[campaign][0] if args.seed is None else args.seed
            if args.search:
                _say(f'{campaign}: Waco 2004 truth, seed {seed}; target per search <= {SEARCH_TARGET_S[campaign]:.0f} s')
                loops.append(run_search(campaign, seed, Path(work), args.baseline))
                continue
            _say(f'{campaign}: Waco 2004 truth, seed {seed}; target per compare '
                 f'<= {TARGET_S[campaign]:.0f} s, <= {TARGET_MEMORY_MB:.0f} MB')
            loops.append(run_loop(campaign, seed, args.rounds, Path(work), args.baseline))
    for loop in loops if not args.search else ():
        _say(f'{loop["campaign"]}: {len(loop["rounds"])} rounds, {loop["loop_compare_s"]:.0f} s of compare, '
              f'slowest round {max(row["wall_s"] for row in loop["rounds"]):.1f} s, '
              f'peak {max(row["peak_mb"] for row in loop["rounds"])} MB; load {load_before:.1f} before')
    commit = subprocess.run(['git', 'rev-parse', '--short', 'HEAD'], cwd=ROOT, capture_output=True,
                            text=True).stdout.strip()
    results = ROOT / 'bench' / 'results'
    results.mkdir(exist_ok=True)
    document = {'date': dt.datetime.now(dt.timezone.utc).isoformat(timespec='seconds'), 'commit': commit,
                'machine': machine_description(), 'load_before': load_before,
                'load_after': os.getloadavg()[0], 'wall_s': round(time.time() - started, 1),
                'baseline': str(args.baseline) if args.baseline else None, 'loops': loops}
    name = ('search_' if args.search else 'compare_loop_') + '_'.join(campaign.replace('-', '_') for campaign in args.campaigns.split(','))
    name += '' if args.seed is None else f'_seed{args.seed}'
    (results / f'{name}.json').write_text(json.dumps(document, indent=1) + '\n')
    (results / f'{name}.txt').write_text(f'{document["date"]} commit {commit}, {document["machine"]}, load '
                                              f'{load_before:.1f} before\n' + '\n'.join(PRINTED) + '\n')


if __name__ == '__main__':
    main()
