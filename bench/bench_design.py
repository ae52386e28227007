"""Benchmark: `sofia design` on issue 28's competing sets, flown and checked (docs/design.md).

For each competing set and seed: the reduced alignment is flown on the nominal truth plus the
set's true member (direct mode); `sofia design BAG --model config/model/nominal.yaml --between
A,B` predicts and writes the plan (timed: issue 28's target is <= 60 s for one set on the
alignment campaign; the library flight is flown once, before the first set, and timed apart);
the plan is flown on the same truth and seed; `sofia design --check` refits both members on the
old and the new bag. Printed and written (bench/results/design.{json,txt}) per row: the
addition's share of the flight, the predicted and achieved separation in the truth's direction,
and whether the truth's member wins by delta-BIC >= 10 before and after.

Temperature against time and tracker drift against a generic period are not here: the simulator
cannot command temperature (docs/plans.md), and the tracker drift is a star-hop effect, whose
element library is not built yet.

Run: .venv/bin/python bench/bench_design.py [--seeds 1,2,3] [--sets hipo,gyro] [--work DIR]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from datetime import datetime, timezone
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parents[1]
SOFIA = str(Path(sys.executable).with_name('sofia'))
MODEL = ROOT / 'config' / 'model' / 'nominal.yaml'
RESULTS = ROOT / 'bench' / 'results'
#: name -> (the truth's member, the rival), as --between spells them
SETS = {
    'hipo': ('hipo_fiducial_error', 'imager_boresight_offset+imager_rotation_of_field'),
    'gyro': ('gyro_axis_swap', 'gyro_scale_factor'),
}
DECIDES = 10.0
TARGET_S = 60.0


def _load() -> str:
    return f'load average {os.getloadavg()[0]:.2f} on {os.cpu_count()} cores'


def _run(arguments: list, log: Path) -> float:
    """Run a sofia command, its output in ``log``; its wall seconds. Fails loudly with the log's tail."""
    started = time.perf_counter()
    done = subprocess.run([SOFIA, *arguments], capture_output=True, text=True)
    log.write_text(done.stdout + done.stderr)
    if done.returncode:
        raise SystemExit(f'{" ".join(arguments[:2])} failed ({done.returncode}): {(done.stdout + done.stderr)[-400:]}')
    return time.perf_counter() - started


def _truth(work: Path, member: str) -> Path:
    document = yaml.safe_load((ROOT / 'config' / 'truth' / 'nominal.yaml').read_text())
    for name in member.split('+'):
        document['effects'][name] = {}
    path = work / f'truth-{member}.yaml'
    path.write_text(yaml.safe_dump(document, sort_keys=False))
    return path


def one_row(work: Path, set_name: str, seed: int) -> dict:
    """Fly, design, fly the design, check: one row of the table."""
    true, rival = SETS[set_name]
    truth = _truth(work, true)
    stem = work / f'{set_name}-seed{seed}'
    old, new = Path(f'{stem}-old'), Path(f'{stem}-new')
    if not (old / 'summary.json').exists():
        _run(['run', 'alignment', '--variant', 'reduced', '--direct', '--seed', str(seed), '--truth', str(truth),
              '--bag', str(old)], Path(f'{stem}-old.log'))
    design_json, plan = Path(f'{stem}-design.json'), Path(f'{stem}-plan.yaml')
    design_s = _run(['design', str(old), '--model', str(MODEL), '--between', f'{true},{rival}', '--plan-out',
                     str(plan), '--json', str(design_json), '--quiet'], Path(f'{stem}-design.txt'))
    design = json.loads(design_json.read_text())
    row = {'set': set_name, 'true': true, 'rival': rival, 'seed': seed, 'design_s': round(design_s, 1),
           'status': design['status'], 'flight_s': design['flight_s'], 'chosen': [e['name'] for e in design['chosen']],
           'flight_share': round(design['flight_share'], 3), 'predicted_before': design['before'][true],
           'predicted_after': design['predicted'][true]}
    check_json = Path(f'{stem}-check.json')
    if design['status'] != 'already_separated':
        if not (new / 'summary.json').exists():
            _run(['run', 'alignment', '--plan', str(plan), '--direct', '--seed', str(seed), '--truth', str(truth),
                  '--bag', str(new)], Path(f'{stem}-new.log'))
        _run(['design', '--check', str(new), '--prediction', str(design_json), '--json', str(check_json), '--quiet'],
             Path(f'{stem}-check.txt'))
        check = json.loads(check_json.read_text())
        for label in ('before', 'after'):
            # Positive: the first member (the truth's) has the lower BIC.
            row[f'achieved_{label}'] = round(check[label]['delta_bic'], 1)
            row[f'wins_{label}'] = check[label]['delta_bic'] >= DECIDES
        achieved, predicted = row['achieved_after'], row['predicted_after']
        row['ratio'] = round(achieved / predicted, 2) if predicted and achieved > 0 and predicted > 0 else None
    return row


def _text(rows: list, header: str) -> str:
    lines = [header, '',
             f'{"set":5} {"seed":>4} {"status":18} {"share":>6} {"predicted before":>16} {"achieved before":>15} '
             f'{"predicted after":>15} {"achieved after":>14} {"wins before/after":>18} {"design s":>9}  chosen']
    for row in rows:
        wins = (f'{"yes" if row.get("wins_before") else "no"}/{"yes" if row.get("wins_after") else "no"}'
                if 'wins_after' in row else '-')
        lines.append(f'{row["set"]:5} {row["seed"]:>4} {row["status"]:18} {100 * row["flight_share"]:5.0f}% '
                     f'{row["predicted_before"]:16.1f} {row.get("achieved_before", float("nan")):15.1f} '
                     f'{row["predicted_after"]:15.1f} {row.get("achieved_after", float("nan")):14.1f} {wins:>18} '
                     f'{row["design_s"]:9.1f}  {", ".join(row["chosen"]) or "-"}')
    return '\n'.join(lines) + '\n'


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--seeds', default='1,2,3')
    parser.add_argument('--sets', default=','.join(SETS))
    parser.add_argument('--work', help='folder for the bags (kept; default: a temporary folder)')
    args = parser.parse_args()
    work = Path(args.work or tempfile.mkdtemp(prefix='bench_design-'))
    work.mkdir(parents=True, exist_ok=True)
    # A cache of its own: the first design flies the element library (its time is in that row's design_s).
    os.environ['XDG_CACHE_HOME'] = str(work / 'cache')
    commit = subprocess.run(['git', '-C', str(ROOT), 'rev-parse', '--short', 'HEAD'], capture_output=True,
                            text=True).stdout.strip()
    started = datetime.now(timezone.utc).strftime('%Y-%m-%d %H:%M UTC')
    rows = []
    for set_name in args.sets.split(','):
        for seed in (int(text) for text in args.seeds.split(',')):
            rows.append(one_row(work, set_name, seed))
            print(_text(rows[-1:], f'{set_name} seed {seed} ({_load()})'), flush=True)
    design_s = [row['design_s'] for row in rows]
    header = (f'sofia design, issue 28: {started}, commit {commit}, {_load()}\n'
              f'reduced alignment (direct mode), model config/model/nominal.yaml, target expected delta-BIC 20 both '
              f'ways, budget 30 % of the flight; a member wins at delta-BIC >= {DECIDES:.0f}\n'
              f'sofia design wall time: {design_s[0]:.1f} s for the first set (the element library flown, cold cache), '
              f'then {min(design_s[1:], default=float("nan")):.1f}-{max(design_s[1:], default=float("nan")):.1f} s '
              f'(target <= {TARGET_S:.0f} s); predicted and achieved delta-BIC in the truth\'s direction '
              f'(positive: the truth\'s member wins)')
    text = _text(rows, header)
    print(text)
    (RESULTS / 'design.txt').write_text(text)
    (RESULTS / 'design.json').write_text(json.dumps({'date': started, 'commit': commit, 'load': _load(),
                                                      'rows': rows}, indent=2) + '\n')


if __name__ == '__main__':
    main()
