"""What a search round fits again and what it reads back (issue 25's performance).

A model the search reaches (compare.search.ReachedModel) starts its ledger's chain where the model it came from was
given its terms, the added term at the refit's values, as `sofia model add` writes them: its chain then shares every
step but the last with that model's and reads them back (compare.steps). Before, the reached model carried the
fitted values for its chain too, and every step of it was fitted again: on the Waco 2004 alignment 52 chain fits in
12 rounds, 16 now, with the same rounds, answer and ledger.

Its whole fit (the start that closes a chain ending in another minimum, test_ledger_given_start) starts where the
refit that proposed it ended, anchors included: the same parameters, already converged, confirmed in one iteration.
It started from the fitted values of the model it came from and the refit's of the new term alone, at zero anchors,
with a time shift's grid: 2.6 s a round on the Waco 2004 star hop, where the chain's last step beside it took 1.5.
"""

from pathlib import Path

import numpy as np
import pytest

from sofia_ros.compare.fit import free_parameters
from sofia_ros.compare.pipeline import _fit_or_none, _ledger
from sofia_ros.compare.run import BagSource
from sofia_ros.compare.search import ReachedModel, _next_model, _Outcome, chain_effects
from sofia_ros.config import load_effect_config
from sofia_ros.effects import resolve_params
from sofia_ros.progress import Progress

ROOT = Path(__file__).resolve().parents[1]
#: The term the step adds, and the value its refit reached (the candidate's entry).
ADDED, REFIT = 'timestamp_offset', {'offset_s': 0.02}


class _Counted(BagSource):
    """A BagSource that counts its fits (chain steps fitted, not read back, and whole fits)."""

    fits = 0

    def _fitted(self, effects, free, start):
        type(self).fits += 1
        return super()._fitted(effects, free, start)


@pytest.fixture(scope='module')
def parent_and_child(campaign_bags):
    """The nominal model's ledger on the reduced alignment, and the model the search reaches from it by adding ADDED."""
    from sofia_ros.compare.observations import read_observations

    observations = read_observations(campaign_bags.reduced_alignment())
    nominal = load_effect_config(ROOT / 'config' / 'model' / 'nominal.yaml')
    parent_rows, parent_fit = _ledger(BagSource(observations, nominal), Progress.silent())
    outcome = _Outcome({'candidates': [{'effect': ADDED, 'params': REFIT}]}, parent_fit.bic, parent_fit.effects)
    child = _next_model(nominal, outcome, {'action': 'add', 'effect': ADDED, 'term': None})
    _Counted.fits = 0
    child_rows, _ = _ledger(_Counted(observations, child), Progress.silent())
    return nominal, parent_fit, parent_rows, child, child_rows, _Counted.fits


def test_the_reached_model_starts_its_chain_where_its_parent_was_given_its_terms(parent_and_child):
    nominal, _, _, child, _, _ = parent_and_child
    assert isinstance(child, ReachedModel)
    assert {name: chain_effects(child)[name] for name in nominal.effects} == nominal.effects
    assert chain_effects(child)[ADDED]['offset_s'] == REFIT['offset_s']


def test_its_whole_fit_starts_from_the_parents_fitted_values(parent_and_child):
    _, parent_fit, _, child, _, _ = parent_and_child
    assert {name: child.effects[name] for name in parent_fit.effects} == parent_fit.effects
    assert child.effects[ADDED]['offset_s'] == REFIT['offset_s']


def test_its_chain_reads_the_parents_steps_back_and_fits_only_its_last_and_the_whole(parent_and_child):
    _, _, parent_rows, _, child_rows, fits = parent_and_child
    assert child_rows[:len(parent_rows)] == parent_rows
    assert [row['term'] for row in child_rows[len(parent_rows):]] == [ADDED]
    assert fits == 2, 'the chain\'s new last step and the whole model from the fitted values; the rest read back'


@pytest.fixture(scope='module')
def refitted_child(campaign_bags, parent_and_child):
    """The same step taken after a refit: the parent's comparison refitted the model with ADDED (as its refits do, from
    the parent's fit) and the search's next model carries where that refit ended."""
    from sofia_ros.compare.observations import read_observations

    nominal, parent_fit, _, _, _, _ = parent_and_child
    observations = read_observations(campaign_bags.reduced_alignment())
    effects = {**parent_fit.effects, ADDED: resolve_params(ADDED, REFIT)}
    refit = BagSource(observations, nominal).fit(effects, parent_fit.free + free_parameters([ADDED]), parent_fit)
    outcome = _Outcome({'candidates': [{'effect': ADDED, 'params': dict(refit.effects[ADDED])}]}, parent_fit.bic,
                       parent_fit.effects, {ADDED: refit.start()})
    child = _next_model(nominal, outcome, {'action': 'add', 'effect': ADDED, 'term': None})
    return observations, refit, child


def test_a_model_reached_by_a_refit_starts_its_whole_fit_where_the_refit_ended(refitted_child):
    observations, refit, child = refitted_child
    effects, start = BagSource(observations, child).given_start()
    assert start is child.refit_start
    assert effects == refit.effects
    np.testing.assert_array_equal(start.anchors_rad, refit.anchors_rad)
    assert set(start.free) == set(refit.free)


def test_there_its_whole_fit_is_the_refit_confirmed_in_one_iteration(refitted_child):
    observations, refit, child = refitted_child
    source = BagSource(observations, child)
    effects, start = source.given_start()
    whole = _fit_or_none(source, effects, start, tuple(start.free))
    # Where a fit from the parent's values at zero anchors took 3-4 iterations and the time shift's grid.
    assert whole.iterations == 1
    # The refit stopped where its step was below 1 % of every sigma: the confirmation moves the chi-square by about
    # 1e-4 a parameter.
    assert whole.bic == pytest.approx(refit.bic, abs=0.01)


def test_a_removed_term_leaves_no_refit_to_start_from(refitted_child):
    _, _, child = refitted_child
    outcome = _Outcome({'candidates': []}, 0.0, dict(child.effects), {ADDED: child.refit_start})
    removed = _next_model(child, outcome, {'action': 'remove', 'effect': None, 'term': ADDED})
    assert removed.refit_start is None
    assert ADDED not in removed.fitted
