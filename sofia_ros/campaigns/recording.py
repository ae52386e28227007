"""Recording a campaign's graph to a bag: in one loop without DDS, every node under one executor, or
every node in its own process."""

from __future__ import annotations

import dataclasses
import tempfile
from pathlib import Path

import yaml

from sofia_ros.bag import BagWriter
from sofia_ros.bag.timebase import epoch_ns_of
from sofia_ros.errors import ConfigError
from sofia_ros.sim.graph import build_cores
from sofia_ros.sim.runner import LockstepRunner
from sofia_ros.sim.scenario import SCENARIO_TOPIC, scenario_document

__all__ = ['MODES', 'graph_documents', 'record_graph', 'new_bag_path']

#: 'executor': every node in this process under one executor, over DDS; 'processes': each node its
#: own process, as `ros2 run` starts them; 'direct': the same cores in one loop without DDS.
MODES = ('executor', 'processes', 'direct')


def new_bag_path(bag_path):
    """The bag directory as a Path; ConfigError if it exists already (a run never overwrites a bag)."""
    bag_path = Path(bag_path)
    if bag_path.exists():
        raise ConfigError(f'bag directory {bag_path} already exists; choose another --bag or remove it')
    return bag_path


def graph_documents(config, model_text=None):
    """(topic, text) of the documents a graph's bag starts with: truth, model (if given), scenario, plan."""
    documents = [('/config/truth', config.truth.text)]
    if model_text is not None:
        documents.append(('/config/model', model_text))
    documents.append((SCENARIO_TOPIC, scenario_document(config.scenario)))
    documents.append(('/config/plan', yaml.safe_dump(dataclasses.asdict(config.plan), sort_keys=False)))
    return documents


def record_graph(config, bag_path, *, model_text, mode, max_sim_s, timeout_s, progress=None):
    """Run the graph of ``config`` until its calibration node finishes, recording every topic to ``bag_path``.

    The bag starts with :func:`graph_documents` in every mode (in 'processes' the recorder
    node builds them from its parameters).
    """
    if mode == 'direct':
        _run_direct(config, bag_path, graph_documents(config, model_text), max_sim_s, progress)
    elif mode == 'executor':
        from sofia_ros.nodes.launch import run_graph_in_process

        run_graph_in_process(config, bag_path, documents=graph_documents(config, model_text), max_sim_s=max_sim_s,
                             timeout_s=timeout_s, progress=progress)
    elif mode == 'processes':
        _run_processes(config, bag_path, model_text, max_sim_s, timeout_s, progress)
    else:
        raise ConfigError(f'mode must be one of {", ".join(MODES)}, got {mode!r}')


def _run_processes(config, bag_path, model_text, max_sim_s, timeout_s, progress):
    """Each node its own process, reading truth and model from files beside its params file."""
    from sofia_ros.nodes.launch import run_graph_in_processes

    with tempfile.TemporaryDirectory(prefix='sofia_run_') as folder:
        truth_file, model_file = Path(folder) / 'truth.yaml', Path(folder) / 'model.yaml'
        truth_file.write_text(config.truth.text)
        model_file.write_text(model_text)
        run_graph_in_processes(truth_file, config.seed, config.plan, bag_path, tick_ns=config.tick_ns,
                               max_sim_s=max_sim_s, timeout_s=timeout_s, model_file=model_file, progress=progress)


def _run_direct(config, bag_path, documents, max_sim_s, progress):
    cores = build_cores(config)
    calibration = cores[-1]
    bag = BagWriter(bag_path, epoch_ns=epoch_ns_of(config.scenario.start_utc))
    bag.open()
    try:
        for topic, text in documents:
            bag.write_document(topic, text, 0)
        runner = LockstepRunner(cores, tick_ns=config.tick_ns, bag=bag)

        def stop():
            if progress is not None:
                progress(runner.stamp_ns / 1e9, max_sim_s)
            return calibration.outcome.finished or calibration.outcome.failed

        runner.run(until_ns=int(max_sim_s * 1e9), stop=stop)
    except BaseException:
        bag.abort()
        raise
    bag.close()
