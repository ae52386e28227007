"""`sofia atlas`: arguments, the run (serial, local cluster or a scheduler), the report.

The arguments are built with every `sofia` command, so the engine, Parquet and plots load only in run_atlas.
"""

from __future__ import annotations

import re
import time
import uuid
from pathlib import Path
from typing import TextIO

from sofia_ros.cli_args import integer, number
from sofia_ros.errors import ConfigError, RunInterrupted
from sofia_ros.output_files import refuse_over_inputs

__all__ = ['TABLE_DIRECTORY', 'add_atlas_arguments', 'run_atlas']

#: OUT/table is the Parquet table (pyarrow.parquet.read_table(OUT/table)); OUT/report the page, OUT/bags the bags.
TABLE_DIRECTORY = 'table'

_AXES = ('effects', 'sizes', 'campaigns', 'seeds')
#: The flags of truths with several effects (a grid file has them as truths, draws, controls, search_rounds).
_TRUTH_FLAGS = ('truths', 'draws', 'draw_k', 'draw_pool', 'draw_seed', 'controls', 'search_rounds')
_DEFAULTS = {'effects': 'all', 'sizes': '0,0.25,0.5,1', 'campaigns': 'alignment:reduced', 'seeds': '5'}


def add_atlas_arguments(parser) -> None:
    """Arguments of `sofia atlas`."""
    parser.add_argument('--out', required=True, help='atlas directory: OUT/table the Parquet table (an existing one '
                                                     'of the same grid is resumed, of another grid refused), OUT/report')
    parser.add_argument('--grid', help='grid YAML (effects, sizes, campaigns, seeds, model, truth, candidates) '
                                       'instead of the flags below')
    parser.add_argument('--effects', help='comma-separated effects to hide (catalogue or plug-ins), or all '
                                          f'(default {_DEFAULTS["effects"]}: every effect the model lacks)')
    parser.add_argument('--sizes', help='comma-separated multiples of each effect\'s default '
                                        f'(default {_DEFAULTS["sizes"]}; 0: nothing hidden)')
    parser.add_argument('--campaigns', help='comma-separated CAMPAIGN[:VARIANT], e.g. alignment:reduced,star-hop:full '
                                            f'(default {_DEFAULTS["campaigns"]})')
    parser.add_argument('--seeds', help=f'N (seeds 1..N), A-B or a comma list (default {_DEFAULTS["seeds"]})')
    parser.add_argument('--model', help='the model compare fits (default config/model/nominal.yaml)')
    parser.add_argument('--truth', help='the truth the effects are hidden in (default config/truth/nominal.yaml)')
    parser.add_argument('--candidates', help='comma-separated effects compare ranks (default: the whole catalogue)')
    parser.add_argument('--truths', help='comma-separated truths hiding several effects at their defaults, each A+B '
                                         '(none: a control); --effects then defaults to none')
    parser.add_argument('--draws', type=integer(1, 1_000_000, 'drawn truths'),
                        help='N truths of k effects drawn at random (each set once) from --draw-pool')
    parser.add_argument('--draw-k', help='effects per drawn truth, cycled: K, K-K or a comma list (default 2,3)')
    parser.add_argument('--draw-pool', help='comma-separated effects to draw from (default: the campaign\'s visible '
                                            'catalogue effects, docs/atlas.md)')
    parser.add_argument('--draw-seed', type=integer(0, 2**32 - 1, 'draw seed'), help='seed of the draws (default 1)')
    parser.add_argument('--controls', type=integer(0, 1_000_000, 'controls'),
                        help='control truths per campaign (nothing hidden; each its own seed)')
    parser.add_argument('--search-rounds', type=integer(1, 20, 'search rounds'),
                        help='search (compare --search) up to N rounds on each truth instead of one compare')
    where = parser.add_mutually_exclusive_group()
    where.add_argument('--scheduler', metavar='tcp://HOST:PORT', help='an existing Dask scheduler (default: a '
                                                                      'LocalCluster on this machine)')
    where.add_argument('--serial', action='store_true', help='no Dask: one task after another in this process')
    parser.add_argument('--workers', type=integer(1, 1024, 'worker processes'),
                        help='LocalCluster worker processes (default: one per core)')
    parser.add_argument('--connect-timeout-s', type=number(0.1, 600.0, 's'), default=10.0,
                        help='give up on an unreachable --scheduler after this long (default 10 s)')
    parser.add_argument('--force', action='store_true', help='run a grid of more than 10000 tasks (up to 1000000)')
    parser.add_argument('--keep-bags', action='store_true', help='keep every bag under OUT/bags (default: deleted)')
    parser.add_argument('--report', help='HTML page directory (default OUT/report)')


def _split(text: str) -> list[str]:
    return [part.strip() for part in text.split(',') if part.strip()]


def _draw_ks(text: str) -> list[int]:
    """--draw-k: K, K-K (a range) or a comma list; ConfigError otherwise."""
    text = text.strip()
    match = re.fullmatch(r'(\d{1,2})-(\d{1,2})', text)
    if match and int(match[1]) <= int(match[2]):
        return list(range(int(match[1]), int(match[2]) + 1))
    if re.fullmatch(r'\d{1,2}(,\d{1,2})*', text):
        return [int(part) for part in text.split(',')]
    raise ConfigError(f'--draw-k {text!r}: give K, a range such as 2-3 or a comma list such as 2,3')


def _truth_arguments(args, max_tasks: int) -> dict:
    """grid_from_lists' truth arguments of the flags; ConfigError for a draw option without --draws."""
    from sofia_ros.atlas.grid import truth_draws

    orphan = next((name for name in ('draw_k', 'draw_pool', 'draw_seed') if getattr(args, name) is not None), None)
    if orphan is not None and args.draws is None:
        raise ConfigError(f'--{orphan.replace("_", "-")} shapes the draws: give --draws N too')
    draws = None
    if args.draws is not None:
        draws = truth_draws(args.draws, _draw_ks(args.draw_k) if args.draw_k is not None else [2, 3],
                            args.draw_seed if args.draw_seed is not None else 1,
                            _split(args.draw_pool) if args.draw_pool is not None else None, max_tasks)
    return {'truths': _split(args.truths) if args.truths is not None else [], 'draws': draws,
            'controls': args.controls or 0, 'search_rounds': args.search_rounds or 0}


def grid_of_arguments(args):
    """The AtlasGrid of --grid, or of the axis and truth flags (with their defaults)."""
    from sofia_ros.atlas.grid import FORCED_MAX_TASKS, MAX_TASKS, grid_from_file, grid_from_lists, seeds_of_text

    max_tasks = FORCED_MAX_TASKS if args.force else MAX_TASKS
    given = [axis for axis in (*_AXES, 'model', 'truth', 'candidates', *_TRUTH_FLAGS)
             if getattr(args, axis) is not None]
    if args.grid is not None:
        if given:
            raise ConfigError(f'--grid and --{given[0].replace("_", "-")} both given; put the whole grid in the file '
                              'or use flags only')
        return grid_from_file(args.grid, max_tasks)
    truths = _truth_arguments(args, max_tasks)
    has_truths = bool(truths['truths']) or truths['draws'] is not None or truths['controls'] > 0
    # with truths, the effects axis is empty unless asked for (its default, all, is a single-effect atlas)
    defaults = {**_DEFAULTS, 'effects': '' if has_truths else _DEFAULTS['effects']}
    value = {axis: getattr(args, axis) if getattr(args, axis) is not None else defaults[axis] for axis in _AXES}
    files = {name: getattr(args, name) for name in ('model', 'truth') if getattr(args, name) is not None}
    return grid_from_lists(effects=_split(value['effects']), sizes=_split(value['sizes']),
                           campaigns=_split(value['campaigns']),
                           seeds=seeds_of_text(value['seeds'], '--seeds', max_tasks) if value['seeds'].strip() else [],
                           candidates=_split(args.candidates) if args.candidates is not None else None,
                           max_tasks=max_tasks, **truths, **files)


def run_atlas(args, out: TextIO, err: TextIO) -> int:
    """Run the missing tasks of the grid, then print the table and write the page."""
    from sofia_ros.atlas.engine import checked_scheduler_address
    from sofia_ros.atlas.report import summarize, text_table, write_html
    from sofia_ros.atlas.store import ResultStore

    if args.scheduler is not None:
        checked_scheduler_address(args.scheduler)
    if args.workers is not None and (args.scheduler is not None or args.serial):
        raise ConfigError('--workers sizes the local cluster; with --scheduler the cluster has its own workers, '
                          'with --serial there are none: leave --workers out')
    grid = grid_of_arguments(args)
    # The page is written after every task has run: a report folder that cannot be one wasted the whole atlas, one
    # inside the table made the table unreadable (pyarrow reads every file there), one over an input replaced it.
    report = Path(args.report) if args.report else Path(args.out) / 'report'
    if args.report:
        if report.exists() and not report.is_dir():
            raise ConfigError(f'--report {report} is a file; give a directory')
        refuse_over_inputs('--report', report, {'the results table': Path(args.out) / TABLE_DIRECTORY,
                                                'the model': grid.model.source, 'the truth': grid.truth.source})
    store = ResultStore(Path(args.out) / TABLE_DIRECTORY, grid.describe())
    total = grid.task_count()
    run_id = f'{time.strftime("%Y%m%dT%H%M%S")}-{uuid.uuid4().hex[:6]}'
    # every stored key is a cell of this grid (the store refuses another grid's parts)
    missing = total - len(store.finished_keys())
    engine = 'serial' if args.serial else (args.scheduler or 'a LocalCluster')
    truths = sum(map(len, grid.truths))
    shape = [f'{len(grid.effects)} effects x {len(grid.sizes)} sizes x {len(grid.campaigns)} campaigns x '
             f'{len(grid.seeds)} seeds'] if grid.effects or not truths else []
    if truths:
        how = f'the search, up to {grid.search_rounds} rounds' if grid.search_rounds else 'one compare'
        shape.append(f'{truths} truths over {len(grid.campaigns)} campaigns ({how}) x {len(grid.seeds)} seeds')
    shape = '; '.join(shape)
    out.write(f'atlas: {total} tasks ({shape}), {total - missing} already in {args.out}; running {missing} on '
              f'{engine} (run {run_id})\n')
    out.flush()
    if missing:
        try:
            _run_missing(args, grid, store, run_id, missing, err)
        except RunInterrupted as interrupted:
            # The campaign's own message names its bag, which the task has deleted by now: tell what is kept.
            stored = len(store.finished_keys())
            raise RunInterrupted(interrupted.signum, f'interrupted by {interrupted.signal_name}; '
                                 f'{store.path} keeps the {stored} of {total} tasks finished; run the same '
                                 f'command again to run the other {total - stored}') from interrupted
    store.compact()
    summary = summarize(store.read().to_pylist())
    out.write(text_table(summary))
    page = write_html(summary, report, str(args.out))
    out.write(f'page: {page}\n')
    return 0


def _run_missing(args, grid, store, run_id: str, missing: int, err: TextIO) -> None:
    """Run the tasks the table lacks, serially or on Dask; their bags in a scratch directory removed at the end."""
    from sofia_ros.atlas.engine import Progress, dashboard_address, dask_client, run_distributed, run_serial
    from sofia_ros.atlas.task import TaskSetup, scratch_directory

    bag_root = str(Path(args.out).resolve() / 'bags') if args.keep_bags else None
    # A remote scheduler's workers run elsewhere: they make their temporary bags in their own /tmp.
    with scratch_directory(local=args.scheduler is None) as scratch:
        setup = TaskSetup(grid.truth, grid.model, grid.candidates, bag_root, run_id, scratch)
        if args.serial:
            run_serial(grid.iter_tasks(), setup, store, Progress(missing, err))
            return
        with dask_client(args.scheduler, workers=args.workers, connect_timeout_s=args.connect_timeout_s) as client:
            progress = Progress(missing, err, dashboard_address(client))
            progress.show(0)
            counts = run_distributed(grid.iter_tasks(), setup, store, client, progress)
    if counts.lost:
        err.write(f'atlas: {counts.lost} tasks lost with their workers (KilledWorker); run the same command '
                  'again to retry them\n')
