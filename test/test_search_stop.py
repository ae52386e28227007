"""When the search stops (issue 25's performance): once it has an explained answer, a queued model is compared only
if it could still end as the answer or an equivalent of it (could_still_count): its expected BIC, less the
estimate's error (EXPECTATION_ERROR_SHARE of how far its parent lies above the answer), within
EQUIVALENT_DELTA_BIC of the answer's path (the lowest BIC it reached with no more terms). The search says why it
ended. Fake comparisons (no bag: milliseconds)."""

from pathlib import Path

import pytest

from sofia_ros.compare.search import EQUIVALENT_DELTA_BIC, EXPECTATION_ERROR_SHARE, could_still_count, search_model
from sofia_ros.config import load_effect_config
from test_search_answer import FakeComparison, FakeFit

ROOT = Path(__file__).resolve().parents[1]
#: The model given (no term added) lacks one effect; FIRST explains it best, RIVAL competes with it.
FIRST, RIVAL = 'gyro_axis_swap', 'gyro_scale_factor'
BIC_GIVEN, BIC_FIRST = 3000.0, 1000.0
#: The highest BIC at which RIVAL, queued from the model given, could still end within EQUIVALENT_DELTA_BIC of FIRST.
REACH = BIC_FIRST + EQUIVALENT_DELTA_BIC + EXPECTATION_ERROR_SHARE * (BIC_GIVEN - BIC_FIRST)


def _fake_compare(outcomes):
    """``outcomes`` maps the terms added to the model given (a frozenset) to (status, BIC, steps), steps being
    [(effect, expected BIC)], the first the verdict's next step and all of them a competing set."""
    nominal = load_effect_config(ROOT / 'config' / 'model' / 'nominal.yaml')

    def compare(observations, model):
        status, bic, steps = outcomes[frozenset(model.fitted - nominal.fitted)]
        candidates = [{'effect': name, 'refined': True, 'params': {}, 'delta_bic': bic - expected}
                      for name, expected in steps]
        step = {'action': 'add', 'effect': steps[0][0], 'term': None} if steps else {'action': 'none',
                                                                                  'effect': None, 'term': None}
        document = {'verdict': {'status': status, 'next': step}, 'candidates': candidates,
                    'competing': [{'effects': [name for name, _ in steps]}] if steps else [],
                    'equivalent_models': [], 'model_change': None, 'residual_rms_arcsec': {'total': 0.3}}
        return FakeComparison(document, FakeFit(bic, {name: dict(params) for name, params in model.effects.items()}))

    return nominal, compare


def _search(rival_expected, rival_bic=BIC_FIRST + 50.0, first_status='explained', rounds=12):
    """The search over the model given, FIRST (at BIC_FIRST) and RIVAL (expected at ``rival_expected``)."""
    nominal, compare = _fake_compare({
        frozenset(): ('missing_effect', BIC_GIVEN, [(FIRST, BIC_FIRST), (RIVAL, rival_expected)]),
        frozenset({FIRST}): (first_status, BIC_FIRST, []),
        frozenset({RIVAL}): ('explained', rival_bic, [])})
    lines = []
    result = search_model(None, nominal, compare, rounds=rounds, progress=lines.append)
    return (*result, lines)


def _compared(rounds):
    return [set(entry['fitted']) for entry in rounds]


def test_a_queued_model_that_cannot_reach_the_answer_is_not_compared():
    _, found, rounds, equivalents, lines = _search(REACH + 1.0)
    assert found.fitted >= {FIRST} and len(rounds) == 2 and not any(RIVAL in fitted for fitted in _compared(rounds))
    assert equivalents == []
    assert rounds[1]['expected_bic'] == BIC_FIRST and rounds[0]['expected_bic'] is None
    assert [entry['ends'] for entry in rounds] == [None, (
        f'explained at BIC {BIC_FIRST:.1f}; nothing queued can reach within 10 of it (not compared: 1 model '
        f'queued, the nearest after round 1: add {RIVAL}, expected at BIC {REACH + 1.0:.1f})')]
    assert lines[-1] == f'search: ends after round 2: {rounds[-1]["ends"]}'


@pytest.mark.parametrize('rival_bic, equivalent', [(BIC_FIRST + 4.0, True), (BIC_FIRST + 60.0, False)],
                         ids=['ends-equivalent', 'ends-far'])
def test_a_queued_model_that_can_reach_it_is_compared(rival_bic, equivalent):
    _, found, rounds, equivalents, _ = _search(REACH - 1.0, rival_bic)
    assert found.fitted >= {FIRST} and any(RIVAL in fitted for fitted in _compared(rounds))
    assert rounds[2]['expected_bic'] == REACH - 1.0
    assert [entry['model'] for entry in equivalents] == ([f'{RIVAL} instead of {FIRST} (compared in full)']
                                                         if equivalent else [])
    assert rounds[-1]['ends'] == 'no comparison suggests a step not yet compared'


def test_before_an_explained_answer_nothing_is_pruned():
    # FIRST is not explained: the rival, however far it is expected to end, is compared, and is the answer.
    _, found, rounds, _, _ = _search(BIC_GIVEN - 1.0, rival_bic=BIC_GIVEN - 1.0, first_status='missing_effect')
    assert found.fitted >= {RIVAL} and len(rounds) == 3
    assert rounds[-1]['ends'] == 'no comparison suggests a step not yet compared'


def test_a_search_cut_by_its_rounds_says_so():
    _, _, rounds, _, _ = _search(REACH - 1.0, rounds=2)
    assert rounds[-1]['ends'] == 'the 2 rounds of --search-rounds are used; not compared: 1 model queued'


@pytest.mark.parametrize('parent_bic, expected_bic, path_bic, counts', [
    (3000.0, 1209.0, 1000.0, True), (3000.0, 1211.0, 1000.0, False),  # 10 % of 2000 above the answer: within 10 + 200
    (1000.0, 1009.0, 1000.0, True), (1000.0, 1011.0, 1000.0, False),  # a parent at the answer: no error allowed for
    (900.0, 1005.0, 1000.0, True),  # a parent below the answer (a non-significant gain) allows no error either
    (3000.0, 2209.0, 2000.0, True), (3000.0, 2211.0, 2000.0, False),  # beside a step of the path at 2000
    (3000.0, 1211.0, 900.0, False)])  # a path below the answer does not lower the bar under the answer's
def test_could_still_count(parent_bic, expected_bic, path_bic, counts):
    assert EXPECTATION_ERROR_SHARE == 0.1  # the cases are computed for it
    assert could_still_count(expected_bic, parent_bic, 1000.0, path_bic) is counts


#: A branch: THIRD closes the model after FIRST or after RIVAL; the two paths end 4 apart.
THIRD = 'hipo_fiducial_error'


def _branch_search(rival_expected):
    nominal, compare = _fake_compare({
        frozenset(): ('missing_effect', BIC_GIVEN, [(FIRST, BIC_FIRST), (RIVAL, rival_expected)]),
        frozenset({FIRST}): ('missing_effect', BIC_FIRST, [(THIRD, 100.0)]),
        frozenset({FIRST, THIRD}): ('explained', 100.0, []),
        frozenset({RIVAL}): ('missing_effect', BIC_FIRST + 3.0, [(THIRD, 104.0)]),
        frozenset({RIVAL, THIRD}): ('explained', 104.0, [])})
    return search_model(None, nominal, compare, rounds=12)


def test_a_rival_beside_the_answers_path_is_followed_to_its_end():
    # The rival is expected 5 above FIRST, far above the answer (100) but within reach of the path's step: its own
    # next step gains what the path gained after FIRST, and ends an equivalent two terms on.
    _, found, rounds, equivalents = _branch_search(BIC_FIRST + 5.0)
    assert found.fitted >= {FIRST, THIRD} and len(rounds) == 5
    assert [entry['model'] for entry in equivalents] == [f'{RIVAL} instead of {FIRST} (compared in full)']
    assert equivalents[0]['delta_bic'] == 4.0


def test_a_rival_out_of_reach_of_the_answers_path_is_not_compared():
    # 10 % of the given model's 2900 above the answer is 290: a rival expected 400 above FIRST is out of reach.
    _, found, rounds, equivalents = _branch_search(BIC_FIRST + EQUIVALENT_DELTA_BIC + 400.0)
    assert found.fitted >= {FIRST, THIRD} and len(rounds) == 3 and equivalents == []
    assert rounds[-1]['ends'].startswith('explained at BIC 100.0; nothing queued can reach within 10 of it')


def test_the_verdicts_choice_in_a_competing_set_is_compared_before_a_rival_expected_lower():
    # The data cannot choose between the members (the rival is expected 8 lower, within the competing margin); the
    # verdict chose FIRST (physics, fewer numbers): FIRST is compared first and is the answer, the rival its
    # equivalent, as in the user's loop.
    nominal, compare = _fake_compare({
        frozenset(): ('missing_effect', BIC_GIVEN, [(FIRST, BIC_FIRST), (RIVAL, BIC_FIRST - 8.0)]),
        frozenset({FIRST}): ('explained', BIC_FIRST, []),
        frozenset({RIVAL}): ('explained', BIC_FIRST - 5.0, [])})
    _, found, rounds, equivalents = search_model(None, nominal, compare, rounds=12)
    assert [sorted(entry['fitted']) for entry in rounds][1:] == [sorted(nominal.fitted | {FIRST}),
                                                                sorted(nominal.fitted | {RIVAL})]
    assert rounds[2]['expected_bic'] == BIC_FIRST - 8.0
    assert found.fitted >= {FIRST}
    assert [entry['model'] for entry in equivalents] == [f'{RIVAL} instead of {FIRST} (compared in full)']
