"""Recording a campaign's graph to a bag: in one loop without DDS, or every node under one executor."""

from __future__ import annotations

from pathlib import Path

from sofia_ros.bag import BagWriter
from sofia_ros.errors import ConfigError
from sofia_ros.sim.graph import build_cores
from sofia_ros.sim.runner import LockstepRunner

__all__ = ['record_graph', 'new_bag_path']


def new_bag_path(bag_path):
    """The bag directory as a Path; ConfigError if it exists already (a run never overwrites a bag)."""
    bag_path = Path(bag_path)
    if bag_path.exists():
        raise ConfigError(f'bag directory {bag_path} already exists; choose another --bag or remove it')
    return bag_path


def record_graph(config, bag_path, documents, *, mode, max_sim_s, timeout_s, progress=None):
    """Run the graph of ``config`` until its calibration node finishes, recording every topic to ``bag_path``."""
    if mode == 'direct':
        _run_direct(config, bag_path, documents, max_sim_s, progress)
    elif mode == 'executor':
        from sofia_ros.nodes.launch import run_graph_in_process

        run_graph_in_process(config, bag_path, documents=documents, max_sim_s=max_sim_s, timeout_s=timeout_s,
                             progress=progress)
    else:
        raise ConfigError(f'mode must be direct or executor here, got {mode!r}')


def _run_direct(config, bag_path, documents, max_sim_s, progress):
    cores = build_cores(config)
    calibration = cores[-1]
    bag = BagWriter(bag_path)
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
