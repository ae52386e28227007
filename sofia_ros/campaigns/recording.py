"""Recording a campaign's graph to a bag: in one loop without DDS, every node under one executor, or
every node in its own process."""

from __future__ import annotations

import json
import os
import shutil
import signal
import sys
import tempfile
import time
from os import PathLike
from pathlib import Path
from typing import Any, Callable, Mapping


from sofia_ros import interrupts
from sofia_ros.bag.timebase import epoch_ns_of
from sofia_ros.errors import ConfigError, OutputError, RunFaultError, RunInterrupted
from sofia_ros.output_files import output_error, write_text_atomically
from sofia_ros.scenario import scenario_document
from sofia_ros.sim.graph import GraphConfig, build_cores
from sofia_ros.sim.runner import LockstepRunner
from sofia_ros.sim.sequence import plan_text
from sofia_ros.topics import MODEL_DOCUMENT, PLAN_DOCUMENT, SCENARIO_DOCUMENT, STOP_DOCUMENT, TRUTH_DOCUMENT

__all__ = ['MODES', 'graph_documents', 'record_campaign', 'record_graph', 'new_bag_path', 'write_summary', 'finish_run',
           'summary_of_failed_run']

#: 'executor': every node in this process under one executor, handing messages over in the process and
#: over DDS what leaves it (nodes.intra_process); 'executor-dds': the same with every message over DDS;
#: 'processes': each node its own process, as `ros2 run` starts them; 'direct': the same cores in one loop
#: without DDS.
MODES = ('executor', 'executor-dds', 'processes', 'direct')


def new_bag_path(bag_path: str | PathLike[str]) -> Path:
    """The bag directory as a Path; ConfigError if it exists already (a run never overwrites a bag), OutputError
    if it cannot be created there (a read-only disk: exit 2), before any node starts."""
    bag_path = Path(bag_path)
    if bag_path.exists():
        raise ConfigError(f'bag directory {bag_path} already exists; choose another --bag or remove it')
    _check_creatable(bag_path)
    return bag_path


def _check_creatable(bag_path: Path) -> None:
    """OutputError unless a directory can be made where ``bag_path`` will be (its nearest existing ancestor).

    Tried with a real directory, since only that tells a read-only disk from a writable one for root
    too; in --processes mode the bag is created by the recorder process, whose own error says less.
    """
    ancestor = next((folder for folder in bag_path.absolute().parents if folder.exists()), Path('/'))
    if not ancestor.is_dir():
        raise ConfigError(f'cannot make bag directory {bag_path}: {ancestor} is a file, not a directory; choose '
                          'another --bag')
    try:
        os.rmdir(tempfile.mkdtemp(prefix=f'.{bag_path.name[:100]}.', dir=ancestor))
    except OSError as err:
        raise output_error(bag_path, err) from err


def graph_documents(config: GraphConfig, model_text: str | None = None) -> list[tuple[str, str]]:
    """(topic, text) of the documents a graph's bag starts with: truth, model (if given), scenario, plan."""
    documents = [(TRUTH_DOCUMENT.name, config.truth.text)]
    if model_text is not None:
        documents.append((MODEL_DOCUMENT.name, model_text))
    documents.append((SCENARIO_DOCUMENT.name, scenario_document(config.scenario)))
    documents.append((PLAN_DOCUMENT.name, plan_text(config.plan)))
    return documents


def write_summary(bag_path: str | PathLike[str], summary: dict) -> None:
    """summary.json beside the bag, whole or not at all (mode from the umask, like every other output)."""
    write_text_atomically(Path(bag_path, 'summary.json'), json.dumps(summary, indent=2) + '\n')


def summary_of_failed_run(bag_path: str | PathLike[str], wall_seconds: float, reason: str) -> dict:
    """The summary of a run whose bag could not be read back (a recorder that died leaves it unclosed)."""
    closed = Path(bag_path, 'metadata.yaml').exists()
    hint = '' if closed or 'sofia recover' in reason else \
        f'; the bag is not closed: rebuild it with `sofia recover {bag_path}`'
    return {'sim_seconds': None, 'wall_seconds': round(wall_seconds, 3), 'reason': reason + hint}


def finish_run(bag_path: str | PathLike[str], summary: dict, fault: str | None = None, *,
               side_files: Mapping[str, str] | None = None) -> None:
    """Write the side files (file name -> text, e.g. truth.yaml) and summary.json beside the bag; raise
    RunInterrupted (a signal stopped the run) or RunFaultError (``fault``).

    An interrupted or faulted run's summary has ``stopped`` ('interrupted' or 'fault') and the reason; these
    files are written whole or not at all, and a stopped run whose disk is full says so in its error line
    rather than losing its reason to the OutputError of summary.json.
    """
    signum = interrupts.requested()
    if signum is not None:
        name = signal.Signals(signum).name
        summary.update(stopped='interrupted', reason=f'interrupted by {name}')
    elif fault:
        # The fault is why the run stopped, with what the recorder could not know (where the node logs are).
        summary.update(stopped='fault', reason=fault)
    recorded = Path(bag_path).is_dir()
    try:
        # The summary first: the reason a stopped run gives matters more than the side files.
        if recorded:
            write_summary(bag_path, summary)
            for file_name, text in (side_files or {}).items():
                write_text_atomically(Path(bag_path, file_name), text)
        where = f'summary.json: "stopped": "{summary.get("stopped")}"'
    except OutputError:
        if signum is None and not fault:
            raise  # the run finished; its files could not be written: that is the error
        where = 'summary.json not written either'
    sim = '' if summary.get('sim_seconds') is None else f' at sim {summary["sim_seconds"]:.1f} s'
    if signum is not None:
        if not recorded:
            raise RunInterrupted(signum, f'interrupted by {name} before the recorder created {bag_path}; '
                                         'nothing was recorded')
        raise RunInterrupted(signum, f'interrupted by {name}{sim}; {bag_path} holds the run up to then ({where})')
    if fault:
        if not recorded:
            raise RunFaultError(f'run stopped{sim}: {summary["reason"]}; nothing was recorded')
        raise RunFaultError(f'run stopped{sim}: {summary["reason"]} ({where})')


def record_campaign(config: GraphConfig, bag_path: Path, **options: Any) -> str | None:
    """record_graph(config, bag_path, **options); when it fails after the start, summary.json gets the
    reason (``"stopped": "fault"``) before the error propagates: RunFaultError (exit 3; also for the bag's
    disk filling up, an OutputError of the writer) or a bug.

    A bag that could not be created at all (its OutputError: exit 2 on a read-only disk) propagates as it is.
    """
    wall_start = time.perf_counter()
    try:
        return record_graph(config, bag_path, **options)
    except (RunFaultError, OutputError) as err:
        if isinstance(err, OutputError) and not Path(bag_path).is_dir():
            raise
        finish_run(bag_path, summary_of_failed_run(bag_path, time.perf_counter() - wall_start, str(err)), str(err))
        raise
    except Exception as err:
        if Path(bag_path).is_dir():
            try:
                write_summary(bag_path, {**summary_of_failed_run(bag_path, time.perf_counter() - wall_start,
                                                                 f'{type(err).__name__}: {err}'), 'stopped': 'fault'})
            except OutputError:
                pass  # a full disk too: the bug's traceback, which follows, matters more
        raise


def record_graph(config: GraphConfig, bag_path: Path, *, model_text: str | None, mode: str, max_sim_s: float,
                 timeout_s: float, progress: Callable[[float | None, float], None] | None = None) -> str | None:
    """Run the graph of ``config`` until its calibration node finishes, recording every topic to ``bag_path``.

    The bag starts with :func:`graph_documents` in every mode (in 'processes' the recorder
    node builds them from its parameters). Returns why the run stopped early (a stall, a signal)
    or None when it ended by itself; the bag is closed either way.
    """
    with interrupts.graceful():
        if mode == 'direct':
            return _run_direct(config, bag_path, graph_documents(config, model_text), max_sim_s, progress)
        if mode in ('executor', 'executor-dds'):
            from sofia_ros.nodes.launch import run_graph_in_process

            _, reason, complete = run_graph_in_process(config, bag_path, documents=graph_documents(config, model_text),
                                                       max_sim_s=max_sim_s, timeout_s=timeout_s, progress=progress,
                                                       intra_process=mode == 'executor')
            return None if complete else reason
        if mode == 'processes':
            return _run_processes(config, bag_path, model_text, max_sim_s, timeout_s, progress)
    raise ConfigError(f'mode must be one of {", ".join(MODES)}, got {mode!r}')


#: What a graph stalled on its first tick on its second start too is told (in place of clock_node.FIRST_TICK_STALL).
_SECOND_FIRST_TICK_STALL = ('; it stalled on its first tick on a second start as well: run it again, or without '
                            '--processes (one process, no DDS between the nodes)')


def _run_processes(config, bag_path, model_text, max_sim_s, timeout_s, progress):
    """Each node its own process, reading truth and model from files beside its params file; returns why the
    run stopped early (the clock's stall reason, as the recorder kept it; a signal) or None. A graph that stalls on
    its first tick (nodes.clock_node.FIRST_TICK_STALL: a fault below this code, nothing recorded yet) is started
    once more on a new bag, with one line on stderr; a second such stall is the run's reason, its note that a new
    start runs cleanly replaced (this was the new start)."""
    from sofia_ros.nodes.clock_node import FIRST_TICK_STALL

    reason, logs = _run_processes_once(config, bag_path, model_text, max_sim_s, timeout_s, progress)
    if reason is None or FIRST_TICK_STALL not in reason or interrupts.requested() is not None:
        return reason
    shutil.rmtree(logs, ignore_errors=True)
    shutil.rmtree(bag_path)
    print(f'running: {reason.split(";", 1)[0]}: the graph stalled on its first tick (a fault of the DDS layer, '
          f'about 1 start in 30 on a loaded machine); starting it again', file=sys.stderr, flush=True)
    again = _run_processes_once(config, bag_path, model_text, max_sim_s, timeout_s, progress)[0]
    return None if again is None else again.replace(FIRST_TICK_STALL, _SECOND_FIRST_TICK_STALL)


def _run_processes_once(config, bag_path, model_text, max_sim_s, timeout_s, progress):
    """One start of the graph in processes (_run_processes): why it stopped early, or None, and the folder of its
    node logs (kept after a fault)."""
    from sofia_ros.bag import BagReader
    from sofia_ros.campaigns.run_parameters import graph_parameters
    from sofia_ros.nodes.clock_node import STALLED_EXIT_CODE
    from sofia_ros.nodes.launch import run_graph_in_processes, silent_nodes

    with tempfile.TemporaryDirectory(prefix='sofia_run_') as folder:
        truth_file, model_file = Path(folder) / 'truth.yaml', Path(folder) / 'model.yaml'
        truth_file.write_text(config.truth.text)
        model_file.write_text(model_text)
        parameters = graph_parameters(truth_file, config.seed, config.plan, tick_ns=config.tick_ns,
                                      max_sim_s=max_sim_s, bag_path=bag_path, model_file=model_file)
        graph = run_graph_in_processes(parameters, bag_path, timeout_s=timeout_s, progress=progress)
    if interrupts.requested() is not None:
        return f'interrupted by {signal.Signals(interrupts.requested()).name}', graph.workdir
    if graph.processes['clock'].returncode != STALLED_EXIT_CODE:
        return None, graph.workdir
    with BagReader(bag_path) as bag:
        reason = bag.document(STOP_DOCUMENT.name)
    silent = silent_nodes(graph)
    return (f'{reason}; node logs in {graph.workdir}' + (f' (nothing logged: {", ".join(silent)})' if silent else ''),
            graph.workdir)


def _run_direct(config, bag_path, documents, max_sim_s, progress):
    """The cores in one loop; a signal (sofia_ros.interrupts) ends it between ticks. Whatever stops
    the loop, the bag is closed with every tick recorded so far."""
    from sofia_ros.bag import BagWriter  # here: node processes import this module, and need no bag writer

    cores = build_cores(config)
    calibration = next(core for core in cores if core.ends_run)
    bag = BagWriter(bag_path, epoch_ns=epoch_ns_of(config.scenario.start_utc))
    bag.open()
    try:
        for topic, text in documents:
            bag.write_document(topic, text, 0)
        runner = LockstepRunner(cores, tick_ns=config.tick_ns, bag=bag)

        def stop():
            if progress is not None:
                progress(runner.stamp_ns / 1e9, max_sim_s)
            return calibration.outcome.finished or calibration.outcome.failed or interrupts.requested() is not None

        runner.run(until_ns=int(max_sim_s * 1e9), stop=stop)
    finally:
        bag.close()
    signum = interrupts.requested()
    return None if signum is None else f'interrupted by {signal.Signals(signum).name}'
