"""The ``sofia`` command (docs/cli.md).

Exit codes: 0 the command ran (a campaign accepted or not: summary.json says which), 2 bad input
(one line on stderr; a read-only output directory too), 3 a run stopped by a fault after it started
(bag closed, summary.json has the reason) or an output the disk had no room for (one line; a bag cut
short keeps what reached the disk, summary.json is whole or absent), 130 / 143 interrupted by SIGINT /
SIGTERM (bag closed, one line), 1 a bug (traceback).
"""

from __future__ import annotations

import json
import sys
import time
import warnings

import yaml

from sofia_ros import interrupts
from sofia_ros.cli_args import OneLineParser, integer, number
from sofia_ros.errors import ConfigError, OutputError, RunFaultError, RunInterrupted, SofiaError
from sofia_ros.output_files import describe_os_error, refuse_empty_paths, refuse_over_inputs
from sofia_ros.plan_limits import PLAN_LIMITS

__all__ = ['main', 'build_parser']


def _print_effects(args):
    from sofia_ros.effects import CATALOGUE, catalogue_as_json

    if args.action == 'new':
        if args.json:
            raise ConfigError('--json prints the catalogue; `sofia effects new` writes a plug-in: drop --json')
        return _new_plugin(args)
    ignored = [option for option, value in (('NAME', args.name), ('--kind', args.kind), ('--dir', args.dir))
               if value is not None]
    if ignored:
        raise ConfigError(f'{", ".join(ignored)} {"goes" if len(ignored) == 1 else "go"} with `sofia effects new NAME '
                          '--kind KIND`; the catalogue takes only --json')
    if args.json:
        json.dump(catalogue_as_json(), sys.stdout, indent=2)
        sys.stdout.write('\n')
        return 0
    for spec in CATALOGUE.values():
        print(f'{spec.name}  [{spec.family}; thesis {spec.thesis}]')
        print(f'    {spec.description}')
        for param in spec.params:
            print(f'    - {param.name} = {param.default} {param.unit}: {param.description}')
    return 0


def _new_plugin(args):
    from sofia_ros.effects.template import write_plugin_template

    if not args.name or not args.kind:
        raise ConfigError('usage: sofia effects new NAME --kind camera|camera-rotation|gyro [--dir DIR]')
    path = write_plugin_template(args.name, args.kind, '.' if args.dir is None else args.dir)
    print(f'{path}: a {args.kind} plug-in; edit its hook, then `export SOFIA_EFFECT_MODULES={args.name} '
          f'PYTHONPATH={path.parent}` and compare again')
    return 0


def _run_demo(args):
    from sofia_ros.demo import run_demo

    return run_demo(out=sys.stdout)


class _Progress:
    """One status line on stderr in sim time; a new line every 10 s when stderr is not a terminal."""

    def __init__(self):
        self.start = time.monotonic()
        self.last = 0.0
        self.tty = sys.stderr.isatty()

    def __call__(self, sim_s, max_sim_s):
        now = time.monotonic()
        if now - self.last < (0.5 if self.tty else 10.0):
            return
        self.last = now
        wall = now - self.start
        if sim_s is None:
            line = f'running: {wall:6.0f} s wall (each node in its own process)'
        else:
            line = f'sim {sim_s:8.1f} s | wall {wall:6.1f} s | {sim_s / max(wall, 1e-9):6.1f}x real time'
        sys.stderr.write(('\r' + line) if self.tty else line + '\n')
        sys.stderr.flush()

    def close(self):
        if self.tty:
            sys.stderr.write('\n')


def _model_text(args):
    """The --model file's text, checked like a truth file (an empty model without --model)."""
    from sofia_ros.config import load_effect_config

    return load_effect_config(args.model).text if args.model else 'effects: {}\n'


#: `sofia run`'s options that only some campaigns take (option dest -> those campaigns): given to another, they
#: were silently ignored.
_CAMPAIGN_OPTIONS = {
    'repetitions': ('alignment',), 'verification_repetitions': ('alignment',), 'drift_track_s': ('alignment',),
    'max_sim_s': ('alignment',), 'hold_s': ('star-hop',), 'observations': ('star-hop',),
    'no_follow_times': ('star-hop',), 'case': ('gyro-stability',), 'hours': ('gyro-stability',),
}


def _check_run_options(campaign, args):
    """ConfigError in one line for an option given an empty value or one that ``campaign`` does not take."""
    for dest in ('truth', 'model', 'bag', 'plan', 'variant'):
        if getattr(args, dest) == '':
            raise ConfigError(f'--{dest} is given an empty value; give one or leave --{dest} out')
    for dest, campaigns in _CAMPAIGN_OPTIONS.items():
        if getattr(args, dest) not in (None, False) and campaign not in campaigns:
            option = '--' + dest.replace('_', '-')
            raise ConfigError(f'{option} is for the {" and ".join(campaigns)} campaign, not {campaign}; drop it')


def _run_campaign(args):
    from sofia_ros.campaigns.registry import campaign_named
    from sofia_ros.config import load_effect_config

    spec = campaign_named(args.campaign)
    _check_run_options(spec.name, args)
    if spec.name == 'gyro-stability':
        return _run_gyro_stability(args)
    if spec.name == 'star-hop':
        return _run_star_hop(spec, args)
    truth = load_effect_config(args.truth)
    model_text = _model_text(args)
    # Options left out take the plan's own values.
    plan = _plan(spec, args, **_given(args, 'repetitions', 'verification_repetitions', 'drift_track_s'))
    progress = _Progress()
    try:
        run = spec.run(truth, seed=args.seed, bag_path=args.bag, plan=plan, mode=_mode(args),
                       model_text=model_text, progress=progress, **_given(args, 'max_sim_s'))
    finally:
        progress.close()
    _print_alignment_summary(run)
    return 0


def _plan(spec, args, **overrides):
    """The run's plan: --plan's file, --variant's named plan or the thesis' (the plan dataclass' defaults, which
    config/plans/CAMPAIGN-full.yaml spells: an install without config/plans runs it too); the options over it."""
    from dataclasses import replace

    from sofia_ros.campaigns.plan_files import read_plan_file

    if args.plan:
        plan = read_plan_file(args.plan, spec.name)
    else:
        plan = spec.plan(args.variant) if args.variant else spec.plan_type()
    return replace(plan, **overrides)


def _given(args, *names):
    """The options among ``names`` given on the command line (argparse leaves the others None)."""
    return {name: getattr(args, name) for name in names if getattr(args, name) is not None}


def _mode(args):
    """The run mode of --processes / --direct / --all-dds (default: every node in one process under an
    executor)."""
    if args.all_dds:
        return 'executor-dds'
    return 'processes' if args.processes else 'direct' if args.direct else 'executor'


def _run_gyro_stability(args):
    from sofia_ros.campaigns.gyro_stability import run_gyro_stability
    from sofia_ros.config import load_effect_config

    if args.case is None:
        raise ConfigError('gyro-stability needs --case TC-1|TC-2|TC-3|TC-4')
    if args.plan or args.variant:
        raise ConfigError('gyro-stability records the gyro box alone and has no plan; drop --plan / --variant')
    if _mode(args) != 'executor':
        raise ConfigError('gyro-stability records the gyro box alone, without a node graph; '
                          'drop --processes / --direct / --all-dds')
    truth = load_effect_config(args.truth)
    progress = _Progress()
    try:
        summary = run_gyro_stability(truth, case=args.case, hours=args.hours, seed=args.seed, bag_path=args.bag,
                                     progress=progress)
    finally:
        progress.close()
    print(f'bag: {args.bag}  ({args.case}: {summary["sim_seconds"]:.1f} s sim, {summary["samples_per_axis"]} samples '
          f'per axis at 400 Hz, in {summary["wall_seconds"]:.1f} s wall)')
    return 0


def _run_star_hop(spec, args):
    from dataclasses import replace

    from sofia_ros.campaigns.star_hop import run_star_hop
    from sofia_ros.config import load_effect_config

    truth = load_effect_config(args.truth)
    model_text = _model_text(args)
    plan = _plan(spec, args)
    observations = plan.observations
    if args.observations is not None:
        first, _, last = args.observations.partition('-')
        try:
            first, last = int(first), int(last or first)
        except ValueError as err:
            raise ConfigError(f'--observations takes FIRST-LAST (1-based, Table D.3), got {args.observations!r}') from err
        if not 1 <= first < last <= len(observations):
            raise ConfigError(f'--observations needs 1 <= FIRST < LAST <= {len(observations)}, got {args.observations}')
        observations = observations[first - 1:last]
    overrides = {'follow_times': False} if args.no_follow_times else {}
    plan = replace(plan, observations=observations, **overrides, **_given(args, 'hold_s'))
    progress = _Progress()
    try:
        summary = run_star_hop(truth, seed=args.seed, bag_path=args.bag, plan=plan, mode=_mode(args),
                               model_text=model_text, progress=progress)
    finally:
        progress.close()
    print(f'bag: {args.bag}  ({summary["sim_seconds"]:.1f} s sim in {summary["wall_seconds"]:.1f} s wall; '
          f'{summary["observations"]} observations)')
    for line in summary.get('elements_skipped', []):
        print(f'sofia run: warning: {line}', file=sys.stderr)
    if not summary['finished']:
        print(f'star hop NOT finished: {summary["reason"]}')
    print(f'analyze it: sofia compare {args.bag} --model {args.model or _nominal_model()}')
    return 0


def _print_alignment_summary(run):
    from sofia_ros.frames import AXES

    summary = run.summary
    print(f'bag: {run.bag_path}  ({summary["sim_seconds"]:.1f} s sim in {summary["wall_seconds"]:.1f} s wall, '
          f'{summary["sim_seconds"] / max(summary["wall_seconds"], 1e-9):.1f}x)')
    if not summary['accepted']:
        print(f'alignment NOT accepted: {summary["reason"]}')
        return
    print(f'alignment accepted after {summary["iterations"]} iteration(s); residual against /truth:')
    print(f'  {"axis":<5} {"residual":>10} {"predicted 1-sigma":>18} {"ratio":>7}')
    for axis in AXES:
        residual = summary['residual_misalignment_arcsec'][axis]
        sigma = summary['predicted_sigma_arcsec'][axis]
        print(f'  {axis.upper():<5} {residual:>9.2f}" {sigma:>17.2f}" {abs(residual) / sigma:>7.2f}')
    print('  predicted sigma: EL/XEL from eq. 3.32 (LOS rotations), LOS from eq. 3.34 (EL/XEL moves), with 3.37')
    _print_flexure_series(yaml.safe_load(run.result_yaml).get('flexure'))


def _print_flexure_series(flexure_record):
    """Imager boresights against HIPO over elevation (Table 3.5, Fig. 6.4) beside the FEM (Table 3.3)."""
    from sofia_ros import flexure
    from sofia_ros.graph_nodes import IMAGERS

    if not flexure_record:
        return
    elevations = [point['elevation_deg'] for point in flexure_record['points']]
    print(f'boresight change against HIPO from 23 to 60 deg (dEL, dXEL), stars at '
          f'{", ".join(f"{e:.1f}" for e in sorted(elevations))} deg:')
    load = flexure.gravity_load_tarf
    for camera in IMAGERS:
        measured = flexure_record['fit'][camera]['change_23_to_60_deg_arcsec']
        fem = (0.0, 0.0) if camera == 'fpi' else flexure.differential_imager_rotation_arcsec(camera, load(60.0), load(23.0))
        print(f'  {camera.upper():<4} measured ({measured[0]:+6.2f}", {measured[1]:+6.2f}")   '
              f'FEM ({fem[0]:+6.2f}", {fem[1]:+6.2f}")   fit rms {flexure_record["fit"][camera]["rms_residual_arcsec"]:.2f}"')


def _replay(args):
    from sofia_ros.nodes.replay import replay_bag

    if args.topics is not None and not all(args.topics):
        raise ConfigError('--topics is given an empty topic name; name the topics to replay (e.g. /clock /fpi/centroids)')
    replay_bag(args.bag, rate=args.rate, topics=args.topics, out=sys.stdout, wait_s=args.wait_s)
    return 0


def _recover(args):
    from sofia_ros.bag.recovery import recover_bag

    refuse_empty_paths(('BAG', args.bag), ('--out', args.out))
    if args.out:
        refuse_over_inputs('--out', args.out, {'the bag': args.bag})
    report = recover_bag(args.bag, args.out)
    ending = 'the file ends cleanly' if report.reached_footer else f'reading stopped: {report.stop_reason}'
    if report.skipped_offsets:
        ending += (f'; skipped {len(report.skipped_offsets)} damaged record(s) at byte(s) '
                   f'{", ".join(str(offset) for offset in report.skipped_offsets[:5])}')
    last = 'no message' if report.last_stamp_ns is None else f'last message at {report.last_stamp_ns / 1e9:.3f} s'
    print(f'recovered {report.message_count} messages on {len(report.topics)} topics into {report.bag} '
          f'({last}; {ending})')
    return 0


def _noise(args):
    from sofia_ros.noise.cli import run_noise

    return run_noise(args)


def _compare(args):
    from sofia_ros.compare.cli import run_compare

    return run_compare(args, sys.stdout)


def _perturb(args):
    from sofia_ros.perturb.cli import run_perturb

    return run_perturb(args, sys.stdout)


def _atlas(args):
    from sofia_ros.atlas.cli import run_atlas

    return run_atlas(args, sys.stdout, sys.stderr)


def _model(args):
    from sofia_ros.compare.cli import run_model_add

    return run_model_add(args, sys.stdout)


def _design(args):
    from sofia_ros.design.cli import run_design

    return run_design(args, sys.stdout)


def _import(args):
    from sofia_ros.bag.csv_logs import import_csv_logs

    refuse_empty_paths(('LOGS', args.logs), ('--bag', args.bag))
    refuse_over_inputs('--bag', args.bag, {'the logs folder': args.logs})
    bag = import_csv_logs(args.logs, args.bag)
    print(f'bag: {bag} (from the CSV logs of {args.logs})')
    print(f'analyze it: sofia compare {bag} --model {_nominal_model()}')
    return 0


def _nominal_model():
    """The shipped nominal model as a command names it from here: config/model/nominal.yaml in the checkout's folder,
    else its whole path (the relative path failed from any other folder)."""
    import os
    from pathlib import Path

    from sofia_ros.input_files import shipped_file

    relative = 'config/model/nominal.yaml'
    found = shipped_file(relative)
    if found is None or Path(relative).resolve() == found.resolve():
        return relative
    return os.path.relpath(found) if found.is_relative_to(Path.cwd()) else str(found)


def _add_noise_arguments(parser):
    from sofia_ros.noise.cli import add_noise_arguments

    add_noise_arguments(parser)


def build_parser():
    """The argument parser with one sub-command per verb."""
    parser = OneLineParser(prog='sofia', description=__doc__.splitlines()[0])
    verbs = parser.add_subparsers(dest='verb', required=True, metavar='COMMAND')

    effects = verbs.add_parser('effects', help='list the catalogue of physical effects, or write a plug-in template')
    effects.add_argument('action', nargs='?', choices=('new',), help='new NAME: write a plug-in template NAME.py')
    effects.add_argument('name', nargs='?', help='new: the effect (and module) name, a lower-case identifier')
    effects.add_argument('--kind', choices=('camera', 'camera-rotation', 'gyro'),
                         help='new: camera (shift on the detector), camera-rotation or gyro (a rate)')
    effects.add_argument('--dir', help='new: folder to write NAME.py into (default: here)')
    effects.add_argument('--json', action='store_true', help='print the catalogue as JSON')
    effects.set_defaults(handler=_print_effects)

    run = verbs.add_parser('run', help='run a campaign of the node graph and record it to a bag')
    run.add_argument('campaign',
                     help='alignment (Table 3.4, 6.1), star-hop (6.2-6.3, Table D.3) or gyro-stability (5.2)')
    run.add_argument('--case', choices=('TC-1', 'TC-2', 'TC-3', 'TC-4'), help='gyro-stability: the test case')
    run.add_argument('--hours', type=number(0.0, 24.0, 'h', low_open=True),
                     help='gyro-stability: record length (default: the case\'s, 4 h or 25 min)')
    run.add_argument('--truth', required=True, help='truth YAML (effects: ...), e.g. config/truth/nominal.yaml')
    run.add_argument('--model', help='model YAML stored with the run (default: no effects)')
    run.add_argument('--seed', type=integer(0, 2**32 - 1, 'a numpy seed'), default=0, help='run seed (default 0)')
    run.add_argument('--bag', required=True, help='output bag directory (must not exist)')
    where = run.add_mutually_exclusive_group()
    where.add_argument('--processes', action='store_true', help='each node in its own process')
    where.add_argument('--direct', action='store_true', help='cores in one loop without DDS (fastest)')
    where.add_argument('--all-dds', action='store_true',
                       help='every node in one process as by default, but every message over DDS as between '
                            'processes (by default the nodes hand messages over in the process)')
    named = run.add_mutually_exclusive_group()
    named.add_argument('--plan', help="the campaign's plan file (docs/plans.md; the options below override its "
                                      'fields), e.g. config/plans/alignment-reduced.yaml')
    named.add_argument('--variant', help='a named plan of the campaign (config/plans/CAMPAIGN-VARIANT.yaml): full '
                                         '(default), reduced, minimal (alignment only)')
    # No defaults here: an option left out takes the plan's value (--plan, --variant, else the plan dataclass'
    # defaults: sim.calibration.AlignmentPlan, sim.star_hop.StarHopPlan) or the campaign runner's (max_sim_s).
    run.add_argument('--repetitions', type=integer(*PLAN_LIMITS['repetitions']),
                     help="maneuvers per axis (default: the plan's, six as in 6.1)")
    run.add_argument('--verification-repetitions', type=integer(*PLAN_LIMITS['verification_repetitions']),
                     help="verification maneuvers per axis (default: the plan's)")
    run.add_argument('--drift-track-s', type=number(*PLAN_LIMITS['drift_track_s']),
                     help="drift estimation on the star, s (default: the plan's)")
    run.add_argument('--max-sim-s', type=number(0.0, 172800.0, 's', low_open=True),
                     help="alignment: stop after this much sim time (default: two hours and the plan elements' "
                          'allowance)')
    run.add_argument('--hold-s', type=number(*PLAN_LIMITS['hold_s'], low_open=True),
                     help="star-hop: seconds each star is held and recorded (default: the plan's)")
    run.add_argument('--no-follow-times', action='store_true',
                     help='star-hop: go to the next star at once instead of at its Table D.3 time')
    run.add_argument('--observations',
                     help="star-hop: only the plan's observations FIRST-LAST (1-based; Table D.3's by default, "
                          'e.g. 4-9)')
    run.set_defaults(handler=_run_campaign)

    replay = verbs.add_parser('replay', help='re-publish a bag on its topics, with /clock, into a live graph')
    replay.add_argument('bag', help='bag directory')
    replay.add_argument('--rate', type=number(0.0, 1e6, 'x real time'), default=1.0,
                        help='speed-up against the recorded time (0: unpaced)')
    replay.add_argument('--topics', nargs='+', help='only these topics')
    replay.add_argument('--wait-s', type=number(0.0, 3600.0, 's'), default=5.0,
                        help='wait this long (wall s) for a subscriber on every replayed topic before publishing')
    replay.set_defaults(handler=_replay)

    recover = verbs.add_parser('recover',
                               help='rebuild a closed bag from one whose writer was killed (SIGKILL, a cut file)')
    recover.add_argument('bag', help='bag directory holding the damaged .mcap')
    recover.add_argument('--out', help='new bag directory (default: BAG_recovered; must not exist)')
    recover.set_defaults(handler=_recover)

    noise = verbs.add_parser('noise', help='noise analysis of a gyro-stability bag (5.2): Earth rate, Allan, lines')
    _add_noise_arguments(noise)
    noise.set_defaults(handler=_noise)

    from sofia_ros.compare.cli import add_compare_arguments, add_model_arguments

    compare = verbs.add_parser('compare', help='fit a model to a campaign bag and rank the effects it lacks')
    add_compare_arguments(compare)
    compare.set_defaults(handler=_compare)

    from sofia_ros.perturb.cli import add_perturb_arguments

    perturb = verbs.add_parser('perturb', help='copy a bag with a what-if shape added to one camera or gyro axis')
    add_perturb_arguments(perturb)
    perturb.set_defaults(handler=_perturb)

    from sofia_ros.atlas.cli import add_atlas_arguments

    atlas = verbs.add_parser('atlas', help='hide each effect at several sizes in many campaigns (Dask), run compare, '
                                           'count: which campaign sees which effect at what size')
    add_atlas_arguments(atlas)
    atlas.set_defaults(handler=_atlas)

    from sofia_ros.design.cli import add_design_arguments

    design = verbs.add_parser('design', help='the plan elements that would tell a competing set apart: predict, '
                                             'write the plan, and --check it once flown')
    add_design_arguments(design)
    design.set_defaults(handler=_design)

    model = verbs.add_parser('model', help='edit a model file: `sofia model add EFFECT --model M.yaml`')
    add_model_arguments(model)
    model.set_defaults(handler=_model)

    imported = verbs.add_parser('import', help='turn plain CSV logs (gyro, encoders, centroids, logbook) into a bag')
    imported.add_argument('logs', help='directory of CSV logs (gyro.csv, gyro_temperature.csv, joints.csv, attitude.csv, '
                                       'centroids.csv, [motion_status.csv], scenario.yaml; docs/thesis-2004.md)')
    imported.add_argument('--bag', required=True, help='output bag directory (must not exist)')
    imported.set_defaults(handler=_import)

    demo = verbs.add_parser('demo', help='worked demonstration of the science core against the thesis tables')
    demo.set_defaults(handler=_run_demo)
    return parser


def _one_line_warning(message, category, filename, lineno, line=None):
    """A warning as `sofia` writes its lines (warnings.formatwarning): Python's named the source file and line and
    printed the source, two lines on every star hop for eq. 6.1's matrix, orthonormal to 1e-5 only."""
    return f'sofia: warning: {message}\n'


def main(argv=None):
    """Entry point of the ``sofia`` console script; returns the exit code (module docstring)."""
    interrupts.reset()
    previous = interrupts.install()
    previous_format, warnings.formatwarning = warnings.formatwarning, _one_line_warning
    try:
        # Building the parser may load the effect catalogue (and the plug-ins it names).
        args = build_parser().parse_args(argv)
        return args.handler(args)
    except SystemExit as done:  # argparse: --help, or a usage error (exit 2 with its usage line)
        return done.code
    except RunInterrupted as err:
        print(f'sofia: {err}', file=sys.stderr)
        return interrupts.EXIT_CODES.get(err.signum, 128 + err.signum)
    except RunFaultError as err:
        print(f'sofia: error: {err}', file=sys.stderr)
        return 3
    except OutputError as err:
        print(f'sofia: error: {err}', file=sys.stderr)
        return err.exit_code
    except SofiaError as err:
        print(f'sofia: error: {err}', file=sys.stderr)
        return 2
    except OSError as err:
        if isinstance(err, BrokenPipeError):
            return 0
        # A command's files on a full, read-only or foreign disk: one line, not a traceback.
        line, exit_code = describe_os_error(err)
        print(f'sofia: error: {line}', file=sys.stderr)
        return exit_code
    finally:
        warnings.formatwarning = previous_format
        interrupts.restore(previous)
        interrupts.reset()


if __name__ == '__main__':
    sys.exit(main())
