"""Benchmark: `sofia design` on issue 28's competing sets, flown and checked (docs/design.md).

For each competing set and seed: the set's campaign is flown on its truth (the nominal truth, or
the one with thermal control, plus the set's true member; direct mode); `sofia design BAG --model
config/model/nominal.yaml --between A,B` predicts and writes the plan (timed: issue 28's target is
<= 60 s for one set on the alignment campaign; a library flight is flown once, by the first
design that needs it, and its time is in that row); the plan is flown on the same truth and seed;
`sofia design --check` refits both members on the old and the new bag. A set that no plan
separates (status inseparable: no plan) is checked on the old bag alone. Printed and written
(bench/results/design.{json,txt}) per row: the addition's share of the flight, the predicted and
achieved separation in the truth's direction, and whether the truth's member wins by delta-BIC
>= 10 before and after.

The sets:
- hipo: HIPO's fiducial error against an equal offset and rotation of the three imagers, reduced
  alignment;
- gyro: swapped gyro calibrations (their temperature coefficient) against a scale-factor error,
  the alignment on the truth with thermal control (config/truth/nominal-thermal.yaml);
- thermal: an FFI tilt that follows the temperature against one that follows time (two one-number
  plug-in effects written by this bench, FFI_TERMS: on a night whose temperature drifts linearly
  they are one signature), the alignment on the truth with thermal control;
- tracker: the tracker drift against the generic period of its length, reduced star hop;
- hipo-hop: the HIPO set on the reduced star hop, whose library places the star off HIPO's centre;
- hipo-min: the HIPO set on the minimal alignment (294 s of flight, one frame per position): whether
  a smaller campaign than the reduced one is blind to it before the addition;
- hipo-rot-hop, hipo-rot: HIPO's fiducial error against a rotation of the imagers' fields, with the imagers'
  boresight offsets in the truth (at the catalogue's values) and fitted in the model, as a real calibration fits
  them, on the reduced star hop and the reduced alignment. The HIPO sets above are decided before any flight by
  the rival's 6 more numbers (its penalty, 6 (ln n - 1)); with the offsets fitted under both, the members have 3
  numbers each and only the data can decide.

Run: .venv/bin/python bench/bench_design.py [--seeds 1,2,3] [--sets hipo,gyro,...] [--work DIR]
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parents[1]
SOFIA = str(Path(sys.executable).with_name('sofia'))
MODEL = ROOT / 'config' / 'model' / 'nominal.yaml'
RESULTS = ROOT / 'bench' / 'results'
DECIDES = 10.0
TARGET_S = 60.0


@dataclass(frozen=True)
class CompetingSet:
    """One row group of the table: the truth's member, its rival, the campaign flown and the truth it is flown on."""

    true: str
    rival: str
    campaign: str
    variant: str
    truth: str
    #: the true member's parameters in the truth file (default: the catalogue's)
    parameters: dict | None = None
    #: effects the truth also holds (at the catalogue's values) and the model fits, so that both members are judged
    #: with them free (default: none, the model config/model/nominal.yaml)
    fitted_in_both: tuple[str, ...] = ()


SETS = {
    'hipo': CompetingSet('hipo_fiducial_error', 'imager_boresight_offset+imager_rotation_of_field', 'alignment',
                         'reduced', 'nominal.yaml'),
    'gyro': CompetingSet('gyro_axis_swap', 'gyro_scale_factor', 'alignment', 'full', 'nominal-thermal.yaml'),
    'thermal': CompetingSet('ffi_thermal_tilt', 'ffi_creep', 'alignment', 'full', 'nominal-thermal.yaml',
                            {'xel_arcsec_per_c': 0.3}),
    'tracker': CompetingSet('tracker_drift', 'empirical:gyro.el:time:period_312s', 'star-hop', 'reduced',
                            'nominal.yaml'),
    'hipo-hop': CompetingSet('hipo_fiducial_error', 'imager_boresight_offset+imager_rotation_of_field', 'star-hop',
                             'reduced', 'nominal.yaml'),
    'hipo-min': CompetingSet('hipo_fiducial_error', 'imager_boresight_offset+imager_rotation_of_field', 'alignment',
                             'minimal', 'nominal.yaml'),
    'hipo-rot-hop': CompetingSet('hipo_fiducial_error', 'imager_rotation_of_field', 'star-hop', 'reduced',
                                 'nominal.yaml', fitted_in_both=('imager_boresight_offset',)),
    'hipo-rot': CompetingSet('hipo_fiducial_error', 'imager_rotation_of_field', 'alignment', 'reduced',
                             'nominal.yaml', fitted_in_both=('imager_boresight_offset',)),
}

#: The thermal set's members: the FFI's frame turned about XEL in proportion to the temperature above the night's
#: start (a mount that bends as it warms) or to the time since the record's start (a mount that creeps). On the
#: nominal night the temperature falls 1 C/h from 22.8 C, so the two are one column until a plan moves the
#: temperature otherwise. Plug-in effects (docs/effects.md), on PYTHONPATH through SOFIA_EFFECT_MODULES.
FFI_TERMS = '''"""The bench's thermal competing set: an FFI tilt with the temperature, and one with time."""

import numpy as np

from sofia_ros.effects.base import EffectSpec, Parameter


def _ffi_about_xel(context, arcsec):
    rotation = np.zeros((len(context), 3))
    if context.camera == 'ffi':
        rotation[:, 1] = arcsec
    return rotation


def ffi_thermal_tilt_rotation_arcsec(params, context):
    """FFI frame about XEL ["]: proportional to the temperature above 22.8 C."""
    return _ffi_about_xel(context, params['xel_arcsec_per_c'] * (context.temperature_c - 22.8))


def ffi_creep_rotation_arcsec(params, context):
    """FFI frame about XEL ["]: proportional to the time since the record's start."""
    return _ffi_about_xel(context, params['xel_arcsec_per_h'] * context.time_s / 3600.0)


EFFECTS = (
    EffectSpec('ffi_thermal_tilt', 'plug-in', 'bench_design', 'FFI tilt about XEL with the temperature',
               (Parameter('xel_arcsec_per_c', 0.0, 'arcsec/C', 'about XEL per C above 22.8 C'),),
               camera_rotation=ffi_thermal_tilt_rotation_arcsec),
    EffectSpec('ffi_creep', 'plug-in', 'bench_design', 'FFI tilt about XEL with time',
               (Parameter('xel_arcsec_per_h', 0.0, 'arcsec/h', 'about XEL per hour of the record'),),
               camera_rotation=ffi_creep_rotation_arcsec),
)
'''


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


def _truth(work: Path, name: str, competing: CompetingSet) -> Path:
    document = yaml.safe_load((ROOT / 'config' / 'truth' / competing.truth).read_text())
    for effect in competing.fitted_in_both:
        document['effects'][effect] = {}
    for member in competing.true.split('+'):
        document['effects'][member] = dict(competing.parameters or {})
    path = work / f'truth-{name}.yaml'
    path.write_text(yaml.safe_dump(document, sort_keys=False))
    return path


def _model(work: Path, name: str, competing: CompetingSet) -> Path:
    """The model both members are fitted with: config/model/nominal.yaml, plus the set's ``fitted_in_both`` as
    fitted terms (`sofia model add`, on a copy beside the bags; `sofia design --check` reads it from the
    prediction's JSON)."""
    if not competing.fitted_in_both:
        return MODEL
    path = work / f'model-{name}.yaml'
    shutil.copyfile(MODEL, path)
    for effect in competing.fitted_in_both:
        _run(['model', 'add', effect, '--model', str(path)], work / f'model-{name}.log')
    return path


def _same_plan(bag: Path, plan: Path) -> bool:
    """Whether a kept bag was flown with ``plan`` (its recorded plan.yaml says the same)."""
    recorded = bag / 'plan.yaml'
    return recorded.is_file() and yaml.safe_load(recorded.read_text()) == yaml.safe_load(plan.read_text())


def _fly(campaign: str, plan_options: list, seed: int, truth: Path, bag: Path, plan: Path | None = None) -> None:
    """Fly a campaign into ``bag``, unless a kept one is there (flown with ``plan``, if given: a design that changed
    flies its plan again)."""
    if (bag / 'summary.json').exists() and plan is not None and not _same_plan(bag, plan):
        shutil.rmtree(bag)
    if not (bag / 'summary.json').exists():
        _run(['run', campaign, *plan_options, '--direct', '--seed', str(seed), '--truth', str(truth), '--bag',
              str(bag)], Path(f'{bag}.log'))


def one_row(work: Path, set_name: str, seed: int) -> dict:
    """Fly, design, fly the design, check: one row of the table."""
    competing = SETS[set_name]
    true, rival = competing.true, competing.rival
    truth = _truth(work, set_name, competing)
    model = _model(work, set_name, competing)
    stem = work / f'{set_name}-seed{seed}'
    old, new = Path(f'{stem}-old'), Path(f'{stem}-new')
    _fly(competing.campaign, ['--variant', competing.variant], seed, truth, old)
    design_json, plan = Path(f'{stem}-design.json'), Path(f'{stem}-plan.yaml')
    design_s = _run(['design', str(old), '--model', str(model), '--between', f'{true},{rival}', '--plan-out',
                     str(plan), '--json', str(design_json), '--quiet'], Path(f'{stem}-design.txt'))
    design = json.loads(design_json.read_text())
    row = {'set': set_name, 'true': true, 'rival': rival, 'campaign': competing.campaign,
           'variant': competing.variant, 'truth': competing.truth, 'seed': seed,
           'fitted_in_both': list(competing.fitted_in_both), 'design_s': round(design_s, 1),
           'status': design['status'], 'flight_s': design['flight_s'], 'chosen': [e['name'] for e in design['chosen']],
           'flight_share': round(design['flight_share'], 3), 'predicted_before': design['before'][true],
           'predicted_after': design['predicted'][true], 'predicted_rival_after': design['predicted'][rival],
           'reproduced': design['reproduced'], 'sizes': design['sizes'][true],
           'assumed_sizes': design['assumed_sizes'][true], 'elements_start_s': design['elements_start_s'],
           'chosen_start_s': [entry['start_s'] for entry in design['elements']
                              if entry['name'] in {chosen['name'] for chosen in design['chosen']}]}
    check_json = Path(f'{stem}-check.json')
    flown = design['status'] in {'designed', 'not_reached'}
    if flown:
        _fly(competing.campaign, ['--plan', str(plan)], seed, truth, new, plan)
    # No plan: the old bag alone is checked (its refit given as the "new" bag too, which is not reported).
    _run(['design', '--check', str(new if flown else old), '--prediction', str(design_json), '--json',
          str(check_json), '--quiet'], Path(f'{stem}-check.txt'))
    check = json.loads(check_json.read_text())
    for label in ('before', 'after') if flown else ('before',):
        # Positive: the first member (the truth's) has the lower BIC.
        row[f'achieved_{label}'] = round(check[label]['delta_bic'], 1)
        row[f'wins_{label}'] = check[label]['delta_bic'] >= DECIDES
    if flown:
        achieved, predicted = row['achieved_after'], row['predicted_after']
        row['ratio'] = round(achieved / predicted, 2) if achieved > 0 and predicted > 0 else None
    return row


def _text(rows: list, header: str) -> str:
    lines = [header, '',
             f'{"set":12} {"seed":>4} {"status":12} {"share":>6} {"predicted before":>16} {"achieved before":>15} '
             f'{"predicted after":>15} {"achieved after":>14} {"ratio":>6} {"wins before/after":>17} '
             f'{"design s":>9}  chosen']
    for row in rows:
        wins = f'{"yes" if row.get("wins_before") else "no"}/' + (
            ("yes" if row["wins_after"] else "no") if 'wins_after' in row else '-')
        # A ratio that rounds to 0.00 (a prediction hundreds of times the achieved) is printed, not hidden as '-'.
        ratio = f'{row["ratio"]:6.2f}' if row.get('ratio') is not None else f'{"-":>6}'
        lines.append(f'{row["set"]:12} {row["seed"]:>4} {row["status"]:12} {100 * row["flight_share"]:5.0f}% '
                     f'{row["predicted_before"]:16.1f} {row.get("achieved_before", float("nan")):15.1f} '
                     f'{row["predicted_after"]:15.1f} {row.get("achieved_after", float("nan")):14.1f} {ratio} '
                     f'{wins:>17} {row["design_s"]:9.1f}  {", ".join(row["chosen"]) or "-"}')
    return '\n'.join(lines) + '\n'


def _with_kept_rows(rows: list) -> list:
    """``rows`` and, for each set not among them, the rows of the last results (bench/results/design.json), in the
    order of SETS; a kept row without its run's date and commit takes the file's."""
    last = json.loads((RESULTS / 'design.json').read_text())
    run = {'date': last['date'], 'commit': last['commit']}
    done = {row['set'] for row in rows}
    kept = [{'run': run, **row} for row in last['rows'] if row['set'] not in done]
    order = list(SETS)
    return sorted([*rows, *kept], key=lambda row: (order.index(row['set']), row['seed']))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--seeds', default='1,2,3')
    parser.add_argument('--sets', default=','.join(SETS))
    parser.add_argument('--work', help='folder for the bags (kept; default: a temporary folder)')
    parser.add_argument('--keep-other-sets', action='store_true',
                        help="keep the rows of bench/results/design.json of the sets not run, with their run's date "
                             'and commit')
    args = parser.parse_args()
    work = Path(args.work or tempfile.mkdtemp(prefix='bench_design-'))
    work.mkdir(parents=True, exist_ok=True)
    # A cache of its own: the first design of each library flies it (its time is in that row's design_s).
    os.environ['XDG_CACHE_HOME'] = str(work / 'cache')
    (work / 'bench_design_terms.py').write_text(FFI_TERMS)
    os.environ['PYTHONPATH'] = os.pathsep.join(filter(None, [str(work), os.environ.get('PYTHONPATH')]))
    os.environ['SOFIA_EFFECT_MODULES'] = 'bench_design_terms'
    commit = subprocess.run(['git', '-C', str(ROOT), 'rev-parse', '--short', 'HEAD'], capture_output=True,
                            text=True).stdout.strip()
    # Where the sofia commands import sofia_ros from (PYTHONPATH may name a clean export of a commit instead of the
    # working tree, which other work in progress may change under a run).
    package = subprocess.run([sys.executable, '-c', 'import sofia_ros; print(sofia_ros.__file__)'], capture_output=True,
                             text=True, cwd=work).stdout.strip()  # not the checkout's folder, which -c would import
    started = datetime.now(timezone.utc).strftime('%Y-%m-%d %H:%M UTC')
    rows = []
    for set_name in args.sets.split(','):
        for seed in (int(text) for text in args.seeds.split(',')):
            rows.append({**one_row(work, set_name, seed), 'run': {'date': started, 'commit': commit,
                                                                  'sofia_ros': package}})
            print(_text(rows[-1:], f'{set_name} seed {seed} ({_load()})'), flush=True)
    if args.keep_other_sets:
        rows = _with_kept_rows(rows)
    # Timed against the target: the designs on the alignment campaign whose library was already flown.
    alignment_s = sorted(row['design_s'] for row in rows if row['campaign'] == 'alignment')
    runs = sorted({(row['run']['date'], row['run']['commit']) for row in rows})
    # The sets whose model (and truth) hold more than the nominal one.
    extra = {}
    for row in rows:
        if row.get('fitted_in_both'):
            extra.setdefault(' '.join(row['fitted_in_both']), set()).add(row['set'])
    fitted_in_both = ''.join(f' (plus, in the truth and fitted, for {", ".join(sorted(sets))}: {effects})'
                             for effects, sets in sorted(extra.items()))
    header = (f'sofia design, issue 28: {"; ".join(f"{date}, commit {run_commit}" for date, run_commit in runs)} '
              f'(each row\'s in design.json; this run\'s sofia_ros: {package}), {_load()}\n'
              f'direct mode, model config/model/nominal.yaml{fitted_in_both}, target expected delta-BIC 20 both ways '
              f'(in the one '
              f'left where the rival reproduces the other), budget 30 % of the flight; a member wins at delta-BIC '
              f'>= {DECIDES:.0f}\n'
              f'sofia design wall time on the alignment campaign: {alignment_s[0] if alignment_s else float("nan"):.1f}'
              f'-{alignment_s[-1] if alignment_s else float("nan"):.1f} s (target <= {TARGET_S:.0f} s; the '
              f'longest includes a library flight); predicted and achieved delta-BIC in the truth\'s direction '
              f'(positive: the truth\'s member wins); ratio achieved / predicted after')
    text = _text(rows, header)
    print(text)
    (RESULTS / 'design.txt').write_text(text)
    (RESULTS / 'design.json').write_text(json.dumps({'date': started, 'commit': commit, 'load': _load(),
                                                      'rows': rows}, indent=2) + '\n')


if __name__ == '__main__':
    main()
