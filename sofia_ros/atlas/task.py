"""One atlas task: a direct-mode campaign (no DDS) with one effect (or a truth's set) hidden, then `sofia compare`
or, for a truth, the search (compare.search.search_model) scored against what was hidden (atlas.scoring).

:func:`run_task` is what a Dask worker (or the serial loop) calls; it returns one row, a plain dict
of the fields in :data:`ROW_FIELDS`. A task that fails returns its row with ``error`` set rather
than raising, so one bad cell never stops the atlas; only a worker that dies makes Dask retry it.
"""

from __future__ import annotations

import json
import math
import shutil
import tempfile
import time
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator

from sofia_ros import interrupts
from sofia_ros.analysis.ranking import SIGNIFICANT_DELTA_BIC
from sofia_ros.atlas.grid import AtlasTask, hidden_truth_text, scaled_params
from sofia_ros.atlas.scoring import score_truth, stated_competitors, stated_pairs
from sofia_ros.campaigns.registry import campaign_named
from sofia_ros.config import EffectConfig, parse_effect_config

__all__ = ['ROW_FIELDS', 'TaskSetup', 'reference_param', 'run_task', 'scratch_directory', 'search_truth_bag']

#: The row of one task: name -> kind ('str', 'float', 'int', 'bool'); the Parquet schema (atlas.store).
ROW_FIELDS = {
    'key': 'str', 'effect': 'str', 'size': 'float', 'campaign': 'str', 'variant': 'str', 'seed': 'int',
    # measurements per axis of the alignment (repetitions x frames, Table 6.5's n); null for a star hop
    'measurements': 'int',
    # the effect's reference parameter (its first scaling one with a non-zero default), true and fitted
    'param': 'str', 'true_value': 'float', 'fitted_value': 'float', 'fitted_sigma': 'float',
    'top_candidate': 'str', 'top_delta_bic': 'float', 'effect_delta_bic': 'float', 'detected': 'bool',
    'degenerate_with': 'str', 'rms_over_floor': 'float', 'verdict': 'str',
    # the alignment campaign's own result against /truth (summary.json) and its predicted 1-sigma
    'misalignment_el_arcsec': 'float', 'misalignment_xel_arcsec': 'float', 'misalignment_los_arcsec': 'float',
    'predicted_sigma_el_arcsec': 'float', 'predicted_sigma_los_arcsec': 'float',
    # a truth task (null for a cell of the effects axis): what was hidden, what the search (or one compare) ended on
    'truth_effects': 'str', 'k': 'int', 'mode': 'str', 'rounds': 'int', 'final_added': 'str', 'final_removed': 'str',
    # JSON: the competing sets the final comparison states (lists of effects), the equivalent models (their labels)
    'competing': 'str', 'equivalents': 'str', 'absorbed': 'str', 'score': 'str',
    'wall_s': 'float', 'error': 'str', 'run_id': 'str',
}


@dataclass(frozen=True)
class TaskSetup:
    """What every task of one atlas shares (pickled once per task to the workers)."""

    truth: EffectConfig
    model: EffectConfig
    candidates: tuple[str, ...] | None
    #: keep each bag under this folder (None: a temporary folder, removed after the compare)
    bag_root: str | None
    #: who ran the row (one id per `sofia atlas` invocation), so a resume shows what it ran
    run_id: str = ''
    #: where the temporary bags go (scratch_directory; None: the worker's own temporary directory)
    scratch_root: str | None = None


@contextmanager
def scratch_directory(local: bool) -> Iterator[str | None]:
    """A directory for the tasks' temporary bags, removed on the way out, or None when not ``local``.

    The invocation removes it, not the tasks: a worker that the closing local cluster kills mid-task
    (Ctrl-C) never runs its own clean-up and left its finished bag in /tmp.
    """
    if not local:
        yield None
        return
    path = tempfile.mkdtemp(prefix='sofia-atlas-')
    try:
        yield path
    finally:
        shutil.rmtree(path, ignore_errors=True)


def reference_param(effect: str) -> tuple[str | None, float]:
    """The first scaling parameter with a non-zero scalar default, and that default (None, nan if none)."""
    for name, value in scaled_params(effect, 1.0).items():
        if isinstance(value, float) and value != 0.0:
            return name, value
    return None, math.nan


def _empty_row(task: AtlasTask, setup: TaskSetup) -> dict:
    row = {name: None for name in ROW_FIELDS}
    row.update(key=task.key, effect=task.effect, size=float(task.size), campaign=task.campaign,
               variant=task.variant, seed=int(task.seed), run_id=setup.run_id)
    return row


def _campaign_fields(plan, summary: dict) -> dict:
    fields = {}
    if hasattr(plan, 'repetitions') and hasattr(plan, 'frames_per_position'):
        fields['measurements'] = int(plan.repetitions * plan.frames_per_position)
    residual = summary.get('residual_misalignment_arcsec')
    if residual:
        predicted = summary['predicted_sigma_arcsec']
        fields.update(misalignment_el_arcsec=residual['el'], misalignment_xel_arcsec=residual['xel'],
                      misalignment_los_arcsec=residual['los'], predicted_sigma_el_arcsec=predicted['el'],
                      predicted_sigma_los_arcsec=predicted['los'])
    return fields


def _comparison_fields(document: dict) -> dict:
    """What every row keeps of a comparison: its best detectable candidate, its verdict and its largest RMS/floor."""
    candidates = document['candidates']
    top = candidates[0] if candidates and candidates[0]['detectable'] else None
    return {'top_candidate': top['effect'] if top else None, 'top_delta_bic': top['delta_bic'] if top else None,
            'verdict': document['verdict']['status'],
            'rms_over_floor': max((o['ratio'] for o in document['verdict']['observables'].values()), default=None)}


def _compare_fields(task: AtlasTask, document: dict) -> dict:
    """The row's compare part: top candidate, the hidden effect's delta-BIC and fitted value, verdict."""
    hidden = next((c for c in document['candidates'] if c['effect'] == task.effect), None)
    param, true_default = reference_param(task.effect)
    fields = {**_comparison_fields(document), 'param': param,
              'true_value': true_default * task.size if param else None,
              'degenerate_with': ','.join(sorted(b if a == task.effect else a for a, b in document['degenerate']
                                                 if task.effect in (a, b))) or None}
    fields['detected'] = bool(fields['top_candidate'] == task.effect
                              and fields['top_delta_bic'] >= SIGNIFICANT_DELTA_BIC)
    if hidden is not None:
        fields['effect_delta_bic'] = hidden['delta_bic']
        if param is not None:
            fields['fitted_value'] = hidden['params'].get(param)
            sigma = hidden['sigma'].get(param)
            # compare keeps an undetermined sigma as inf in memory and null in its JSON: rows say null too.
            fields['fitted_sigma'] = sigma if sigma is not None and math.isfinite(sigma) else None
    return fields


def _joined(names) -> str:
    return ','.join(sorted(names))


def _truth_fields(task: AtlasTask, model: EffectConfig, result, final: EffectConfig, rounds: int,
                  equivalents: list) -> dict:
    """The row's truth part: what was hidden, the final model against the one given, its competitors, the score."""
    document = result.document
    added, removed = sorted(final.fitted - model.fitted), sorted(model.fitted - final.fitted)
    status = document['verdict']['status']
    competing = stated_competitors(document)
    absorbed = sorted(set(task.hidden) & set(document['unobservable']))
    return {'truth_effects': _joined(task.hidden), 'k': len(task.hidden),
            'mode': 'search' if task.search_rounds else 'compare', 'rounds': rounds,
            'final_added': _joined(added), 'final_removed': _joined(removed),
            'competing': json.dumps(competing), 'equivalents': json.dumps([entry['model'] for entry in equivalents]),
            'absorbed': _joined(absorbed),
            'score': score_truth(task.hidden, added, removed, status, stated_pairs(competing, equivalents), absorbed)}


def search_truth_bag(task: AtlasTask, setup: TaskSetup, bag_path: Path) -> dict:
    """A truth's bag searched for ``task.search_rounds`` rounds (or compared once); the row's truth fields."""
    from sofia_ros.compare.observations import read_observations
    from sofia_ros.compare.run import compare_observations
    from sofia_ros.compare.search import search_model

    observations = read_observations(bag_path)

    def compare(observed, model):
        return compare_observations(observed, model, candidate_names=setup.candidates)

    if task.search_rounds:
        # Each round is a whole comparison: a Ctrl-C of `--serial` stops the search between rounds.
        result, final, rounds, equivalents = search_model(
            observations, setup.model, compare, rounds=task.search_rounds,
            progress=lambda line: interrupts.raise_if_requested())
        count = len(rounds)
    else:
        result, final, count = compare(observations, setup.model), setup.model, 1
        equivalents = result.document['equivalent_models']
    return {**_comparison_fields(result.document),
            **_truth_fields(task, setup.model, result, final, count, equivalents)}


def run_task(task: AtlasTask, setup: TaskSetup) -> dict:
    """Run one cell: campaign in direct mode with the effect (or the truth's set) hidden, compare against the model
    (a truth: search, or compare once, and score); one row."""
    from sofia_ros.compare.run import compare_bag

    started = time.perf_counter()
    row = _empty_row(task, setup)
    if setup.bag_root is None:
        work = Path(tempfile.mkdtemp(prefix='sofia-atlas-', dir=setup.scratch_root))
        bag_path = work / 'bag'
    else:
        work = None
        bag_path = Path(setup.bag_root) / task.key.replace('|', '_')
        shutil.rmtree(bag_path, ignore_errors=True)  # a retry after a killed worker starts afresh
    try:
        spec = campaign_named(task.campaign)
        plan = spec.plan(task.variant)
        # a cell keeps its effect at size 0 (its parameters zeroed); a truth hides its set, a control nothing
        hidden = task.effect if task.truth_index is None else task.hidden
        truth = parse_effect_config(hidden_truth_text(setup.truth, hidden, task.size),
                                    f'{setup.truth.source} with {task.effect} at {task.size:g}x')
        run = spec.run(truth, seed=task.seed, bag_path=str(bag_path), plan=plan, mode='direct',
                       model_text=setup.model.text)
        # the alignment returns an AlignmentRun, the star hop its summary
        interrupts.raise_if_requested()  # `--serial` and Ctrl-C: the campaign stopped early, compare nothing
        row.update(_campaign_fields(plan, run.summary if hasattr(run, 'summary') else run))
        if task.truth_index is None:
            result = compare_bag(bag_path, setup.model, candidate_names=setup.candidates)
            row.update(_compare_fields(task, result.document))
        else:
            row.update(search_truth_bag(task, setup, bag_path))
    except Exception as err:  # one failed cell is a row with its error, never a stopped atlas
        row['error'] = f'{type(err).__name__}: {err}'.splitlines()[0][:500]
    finally:
        if work is not None:
            shutil.rmtree(work, ignore_errors=True)
    row['wall_s'] = time.perf_counter() - started
    return row
