"""Recording a campaign's graph to a bag: in one loop without DDS, every node under one executor, or
every node in its own process."""

from __future__ import annotations

import dataclasses
import json
import signal
import tempfile
import time
from os import PathLike
from pathlib import Path
from typing import Any, Callable, Mapping

import yaml

from sofia_ros import interrupts
from sofia_ros.bag import BagWriter
from sofia_ros.bag.timebase import epoch_ns_of
from sofia_ros.errors import ConfigError, RunFaultError, RunInterrupted
from sofia_ros.scenario import scenario_document
from sofia_ros.sim.graph import GraphConfig, build_cores
from sofia_ros.sim.runner import LockstepRunner
from sofia_ros.topics import MODEL_DOCUMENT, PLAN_DOCUMENT, SCENARIO_DOCUMENT, STOP_DOCUMENT, TRUTH_DOCUMENT

__all__ = ['MODES', 'graph_documents', 'record_campaign', 'record_graph', 'new_bag_path', 'write_summary', 'finish_run',
           'summary_of_failed_run']

#: 'executor': every node in this process under one executor, handing messages over in the process and
#: over DDS what leaves it (nodes.intra_process); 'executor-dds': the same with every message over DDS;
#: 'processes': each node its own process, as `ros2 run` starts them; 'direct': the same cores in one loop
#: without DDS.
MODES = ('executor', 'executor-dds', 'processes', 'direct')


def new_bag_path(bag_path: str | PathLike[str]) -> Path:
    """The bag directory as a Path; ConfigError if it exists already (a run never overwrites a bag)."""
    bag_path = Path(bag_path)
    if bag_path.exists():
        raise ConfigError(f'bag directory {bag_path} already exists; choose another --bag or remove it')
    return bag_path


def graph_documents(config: GraphConfig, model_text: str | None = None) -> list[tuple[str, str]]:
    """(topic, text) of the documents a graph's bag starts with: truth, model (if given), scenario, plan."""
    documents = [(TRUTH_DOCUMENT.name, config.truth.text)]
    if model_text is not None:
        documents.append((MODEL_DOCUMENT.name, model_text))
    documents.append((SCENARIO_DOCUMENT.name, scenario_document(config.scenario)))
    documents.append((PLAN_DOCUMENT.name, yaml.safe_dump(dataclasses.asdict(config.plan), sort_keys=False)))
    return documents


def write_summary(bag_path: str | PathLike[str], summary: dict) -> None:
    """summary.json beside the bag (mode from the umask, like every other output)."""
    Path(bag_path, 'summary.json').write_text(json.dumps(summary, indent=2) + '\n')


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

    An interrupted or faulted run's summary has ``stopped`` ('interrupted' or 'fault') and the reason.
    """
    for name, text in (side_files or {}).items():
        Path(bag_path, name).write_text(text)
    signum = interrupts.requested()
    if signum is not None:
        name = signal.Signals(signum).name
        summary.update(stopped='interrupted', reason=f'interrupted by {name}')
    elif fault:
        # The fault is why the run stopped, with what the recorder could not know (where the node logs are).
        summary.update(stopped='fault', reason=fault)
    if Path(bag_path).is_dir():
        write_summary(bag_path, summary)
    sim = '' if summary.get('sim_seconds') is None else f' at sim {summary["sim_seconds"]:.1f} s'
    if signum is not None:
        if not Path(bag_path).is_dir():
            raise RunInterrupted(signum, f'interrupted by {name} before the recorder created {bag_path}; '
                                         'nothing was recorded')
        raise RunInterrupted(signum, f'interrupted by {name}{sim}; {bag_path} holds the run up to then '
                                     '(summary.json: "stopped": "interrupted")')
    if fault:
        raise RunFaultError(f'run stopped{sim}: {summary["reason"]} (summary.json: "stopped": "fault")')


def record_campaign(config: GraphConfig, bag_path: Path, **options: Any) -> str | None:
    """record_graph(config, bag_path, **options); when it fails after the start, summary.json gets the
    reason (``"stopped": "fault"``) before the error propagates: RunFaultError (exit 3) or a bug."""
    wall_start = time.perf_counter()
    try:
        return record_graph(config, bag_path, **options)
    except RunFaultError as err:
        finish_run(bag_path, summary_of_failed_run(bag_path, time.perf_counter() - wall_start, str(err)), str(err))
        raise
    except Exception as err:
        if Path(bag_path).is_dir():
            write_summary(bag_path, {**summary_of_failed_run(bag_path, time.perf_counter() - wall_start,
                                                             f'{type(err).__name__}: {err}'), 'stopped': 'fault'})
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


def _run_processes(config, bag_path, model_text, max_sim_s, timeout_s, progress):
    """Each node its own process, reading truth and model from files beside its params file; returns why the
    run stopped early (the clock's stall reason, as the recorder kept it; a signal) or None."""
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
        return f'interrupted by {signal.Signals(interrupts.requested()).name}'
    if graph.processes['clock'].returncode != STALLED_EXIT_CODE:
        return None
    with BagReader(bag_path) as bag:
        reason = bag.document(STOP_DOCUMENT.name)
    silent = silent_nodes(graph)
    return f'{reason}; node logs in {graph.workdir}' + (f' (nothing logged: {", ".join(silent)})' if silent else '')


def _run_direct(config, bag_path, documents, max_sim_s, progress):
    """The cores in one loop; a signal (sofia_ros.interrupts) ends it between ticks. Whatever stops
    the loop, the bag is closed with every tick recorded so far."""
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
