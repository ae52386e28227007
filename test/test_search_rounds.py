"""What a search round fits again and what it reads back (issue 25's performance).

A model the search reaches (compare.search.ReachedModel) starts its ledger's chain where the model it came from was
given its terms, the added term at the refit's values, as `sofia model add` writes them: its chain then shares every
step but the last with that model's and reads them back (compare.steps). Its whole fit still starts from the fitted
values of the model it came from and the refit's of the new term (the start that closes a chain ending in another
minimum, test_ledger_given_start). Before, the reached model carried the fitted values for its chain too, and every
step of it was fitted again: on the Waco 2004 alignment 52 chain fits in 12 rounds, 16 now, with the same rounds,
answer and ledger.
"""

from pathlib import Path

import pytest

from sofia_ros.compare.pipeline import _ledger
from sofia_ros.compare.run import BagSource
from sofia_ros.compare.search import ReachedModel, _next_model, _Outcome, chain_effects
from sofia_ros.config import load_effect_config
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
