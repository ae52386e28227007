"""The search when a comparison's fit loses the minimum its refit found (issue 25, the multi-effect atlas' truth12).

A comparison fits its model along the ledger (each term in the model's order, from the one before).
On the reduced alignment with a gyro scale factor, an imager rotation of field and an imager scale
error hidden, the model of exactly those three, with the scale factor added last, ended 139,000 BIC
above the refit that proposed it; the search then added a HIPO fiducial error the truth lacks to
escape, and ended explained on four terms. A fake comparison with that behaviour (no bag: the test
takes milliseconds) holds the search to comparing the same terms again along another path.
"""

from dataclasses import dataclass
from pathlib import Path

import pytest

from sofia_ros.compare.search import search_model
from sofia_ros.config import load_effect_config

ROOT = Path(__file__).resolve().parents[1]
#: The hidden effects, in the order the search adds them (the strongest first).
TRUTH = ('imager_scale_error', 'imager_rotation_of_field', 'gyro_scale_factor')
#: What the search adds to escape a lost minimum: a term the truth lacks.
ESCAPE = 'hipo_fiducial_error'
BIC_EXPLAINED = 1000.0
#: Each hidden effect the model lacks, and each term it has that the truth lacks, cost this much BIC.
MISSING_BIC, EXTRA_BIC = 100_000.0, 30.0


@dataclass
class _Fit:
    bic: float
    effects: dict


@dataclass
class _Comparison:
    document: dict
    final_fit: _Fit


def _bic(terms):
    return BIC_EXPLAINED + MISSING_BIC * len(set(TRUTH) - terms) + EXTRA_BIC * len(terms - set(TRUTH) - {ESCAPE})


def _fake_compare(stuck_bic):
    """A comparison whose ledger, given the three hidden effects with the gyro scale factor fitted after both imager
    terms, ends ``stuck_bic`` above their minimum (the imager terms have taken its part); any other path finds it."""
    nominal = load_effect_config(ROOT / 'config' / 'model' / 'nominal.yaml')

    def compare(observations, model):
        terms = set(model.fitted - nominal.fitted)
        order = [name for name in model.effects if name in terms]
        stuck = terms == set(TRUTH) and order.index('gyro_scale_factor') == len(order) - 1
        bic = _bic(terms) + (stuck_bic if stuck else 0.0)
        missing = [name for name in TRUTH if name not in terms]
        explained = not missing and bic < BIC_EXPLAINED + MISSING_BIC / 100
        # the refit of the next term reaches the minimum of the terms with it (escaping, with ESCAPE)
        following = missing[0] if missing else None if explained else ESCAPE
        candidates = [] if following is None else [{
            'effect': following, 'refined': True, 'params': {},
            'delta_bic': bic - (BIC_EXPLAINED + EXTRA_BIC if following == ESCAPE else _bic(terms | {following}))}]
        step = {'action': 'add' if following else 'none', 'effect': following, 'term': None}
        document = {'verdict': {'status': 'explained' if explained else 'missing_effect', 'next': step},
                    'candidates': candidates, 'competing': [], 'equivalent_models': [], 'model_change': None,
                    'residual_rms_arcsec': {'total': 0.3 if explained else 5.0}}
        return _Comparison(document, _Fit(bic, {name: dict(params) for name, params in model.effects.items()}))

    return nominal, compare


def test_a_comparison_that_lost_its_refits_minimum_is_compared_again_newest_term_first():
    nominal, compare = _fake_compare(stuck_bic=139_000.0)
    result, found, rounds, _ = search_model(None, nominal, compare)
    assert sorted(found.fitted - nominal.fitted) == sorted(TRUTH)
    assert result.document['verdict']['status'] == 'explained' and result.final_fit.bic == BIC_EXPLAINED
    lost, again = rounds[3], rounds[4]
    assert lost['moves'] == ['add gyro_scale_factor, the terms added fitted newest first: this fit ended at BIC '
                             '140000, the refit that proposed it at 1000']
    assert again['fitted'] == lost['fitted'] and again['status'] == 'explained' and len(rounds) == 5
    assert not any(ESCAPE in entry['fitted'] for entry in rounds)


@pytest.mark.parametrize('stuck_bic', [0.0, 500.0], ids=['same-minimum', 'within-the-competing-margin'])
def test_a_comparison_near_its_refit_is_not_compared_again(stuck_bic):
    nominal, compare = _fake_compare(stuck_bic)
    _, found, rounds, _ = search_model(None, nominal, compare)
    assert sorted(found.fitted - nominal.fitted) == sorted(TRUTH) and len(rounds) == 4
    assert not any('newest first' in move for entry in rounds for move in entry['moves'])
