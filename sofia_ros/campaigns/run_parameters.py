"""The node parameters of one run (campaign, truth file, seed, plan, tick), as every node of the graph takes them.

The plan is the campaign's plan dataclass, one parameter ``plan.<field>`` per field (tuples as
arrays). A field of rows whose dataclass metadata names its ``columns`` is one array per column,
``plan.<field>.<column>``: the star hop's observations are ``plan.observations.star`` (string
array) and ``plan.observations.offset_s`` (double array, seconds after Table D.3's first
observation), entry i of both being observation i. ``campaigns.recording`` writes them for a run
whose nodes are processes (nodes.launch puts them in a --params-file); each node executable reads
them back with ``campaigns.graph_params``. No registry here: the recording side imports this module.
"""

from __future__ import annotations

from dataclasses import fields
from os import PathLike
from typing import Any

__all__ = ['graph_parameters', 'plan_parameters']


def graph_parameters(truth_file: str | PathLike[str], seed: int, plan: Any, *, tick_ns: int, max_sim_s: float,
                     bag_path: str | PathLike[str] = '', stall_timeout_s: float = 15.0,
                     model_file: str | PathLike[str] = '') -> dict[str, Any]:
    """Parameter values of one run; the campaign is the one ``plan`` plans (its dataclass' ``campaign``)."""
    return {'campaign': plan.campaign, 'truth_file': str(truth_file), 'seed': int(seed), 'tick_ns': int(tick_ns),
            'max_sim_s': float(max_sim_s), 'stall_timeout_s': float(stall_timeout_s), 'bag_path': str(bag_path),
            'model_file': str(model_file), **plan_parameters(plan)}


def plan_parameters(plan: Any) -> dict[str, Any]:
    """The plan as plan.* parameter values: one per field, a field with ``columns`` one array per column."""
    values = {}
    for spec in fields(plan):
        value = getattr(plan, spec.name)
        columns = spec.metadata.get('columns')
        if columns:
            values.update({f'plan.{spec.name}.{column}': list(rows) for column, rows in zip(columns, zip(*value))})
        else:
            values[f'plan.{spec.name}'] = list(value) if isinstance(value, tuple) else value
    return values
