"""Two model terms standing in for one physical effect the model absorbs (issue 25, the multi-effect atlas' truth29).

On the reduced star hop with a gyro axis swap and an imager rotation of field hidden, the search ended
`explained` on a gyro scale factor and a LOS oscillation for the swap: the scale factor absorbs the
swap's scale difference, so the swap was not observable beside it, was left out of the candidates a
model's terms are questioned against, and was never tried in their place; and the oscillation, switched
off by the linearization with its period and phase far from their defaults, seemed to pay for itself.
A linear problem with those shapes (no bag: the tests take milliseconds) holds the linearized search to
proposing the swap in the place of both.
"""

import numpy as np
import pytest
import scipy.sparse

from sofia_ros.analysis.ranking import CandidateTerm
from sofia_ros.compare.fit import free_parameters
from sofia_ros.compare.search import SEARCH_POOL, LinearizedModels, model_terms, search_pool, structural_changes

ROWS = 3000
ANCHORS = 6
#: The oscillation's fitted period and phase, far from their defaults (1200 s, 0 deg), as truth29's round 5 had them.
PERIOD_S, PHASE_DEG = 511.0, -543.0


def _stand_in_problem(seed=3):
    """A fitted model of gyro_bias, gyro_scale_factor and los_oscillation on data of gyro_bias and a gyro axis swap.

    The swap's two columns: its scale difference (the scale factor's own column) and its temperature slope
    (which the oscillation's amplitude column follows only in part). Returns the residual, Jacobian (anchors
    first), free parameters and values of the fit, the candidate terms and their JSON entries, and the columns.
    """
    rng = np.random.default_rng(seed)
    bias, scale, slope, other = (rng.standard_normal(ROWS) for _ in range(4))
    # the oscillation's columns: period, amplitude, phase
    oscillation = [rng.standard_normal(ROWS), slope + 0.5 * other, rng.standard_normal(ROWS)]
    nuisance = rng.standard_normal((ROWS, ANCHORS))
    data = bias + scale + 0.3 * slope + rng.standard_normal(ROWS)
    design = np.column_stack([nuisance, bias, scale, *oscillation])
    solution, *_ = np.linalg.lstsq(design, data, rcond=None)
    residual = data - design @ solution
    # One parameter of gyro_bias and of the scale factor stands for each; the oscillation has all three of its own.
    free = (free_parameters(['gyro_bias'])[0], free_parameters(['gyro_scale_factor'])[0],
            *free_parameters(['los_oscillation']))
    period, amplitude, phase = solution[ANCHORS + 2:]
    values = np.array([solution[ANCHORS], solution[ANCHORS + 1], PERIOD_S + period, amplitude, PHASE_DEG + phase])
    jacobian = scipy.sparse.csr_matrix(design)
    swap = CandidateTerm('gyro_axis_swap', ('scale_difference_ppm', 'scale_temperature_coefficient_ppm_per_c'),
                         np.zeros(2), np.column_stack([scale, slope]))
    heading = CandidateTerm('heading_error', ('heading_error_deg',), np.zeros(1), bias[:, None])
    shape = CandidateTerm('empirical:fpi.x:time:period_312s', ('a',), np.zeros(1), rng.standard_normal((ROWS, 1)))
    entries = [
        # not observable beside the scale factor, which absorbs its scale difference; its slope is measured
        {'effect': 'gyro_axis_swap', 'detectable': False, 'delta_bic': -24.0, 'empirical': False,
         'sigma': {'scale_difference_ppm': np.inf, 'scale_temperature_coefficient_ppm_per_c': 7.5}},
        # absorbed whole by gyro_bias: the comparison names the two degenerate
        {'effect': 'heading_error', 'detectable': False, 'delta_bic': 0.0, 'empirical': False,
         'sigma': {'heading_error_deg': np.inf}},
        {'effect': 'empirical:fpi.x:time:period_312s', 'detectable': False, 'delta_bic': -8.0, 'empirical': True,
         'sigma': {'a': 1.0}},
    ]
    return residual, jacobian, free, values, [swap, heading, shape], entries, (bias, scale, oscillation[1])


def test_a_term_switched_off_gives_back_its_part_alone_whatever_its_period_and_phase():
    residual, jacobian, free, values, _, _, (bias, scale, amplitude_column) = _stand_in_problem()
    models = LinearizedModels.at_fit(residual, jacobian, free, values, ANCHORS, [])
    # Without the oscillation its amplitude times its column is back in the residual: a direct solve of that.
    target = residual + values[3] * amplitude_column
    design = np.column_stack([jacobian[:, :ANCHORS].toarray(), bias, scale])
    solution, *_ = np.linalg.lstsq(design, target, rcond=None)
    direct = float(np.sum((target - design @ solution) ** 2))
    assert models.rss({'gyro_bias', 'gyro_scale_factor'}) == pytest.approx(direct, rel=1e-9)


def test_the_pool_holds_a_physical_effect_the_model_absorbs_in_part():
    *_, terms, entries, _ = _stand_in_problem()
    strong = [{'effect': f'strong_{i}', 'detectable': True, 'delta_bic': float(100 - i), 'empirical': False,
               'sigma': {'p': 1.0}} for i in range(SEARCH_POOL + 2)]
    strong_terms = [CandidateTerm(entry['effect'], ('p',), np.zeros(1), np.zeros((1, 1))) for entry in strong]
    pool = search_pool([term.name for term in [*terms, *strong_terms]], [*entries, *strong])
    assert pool == ['gyro_axis_swap', *(f'strong_{i}' for i in range(SEARCH_POOL))]


def test_two_terms_standing_in_for_one_physical_effect_make_way_for_it():
    residual, jacobian, free, values, terms, entries, _ = _stand_in_problem()
    pool = search_pool([term.name for term in terms], entries)
    models = LinearizedModels.at_fit(residual, jacobian, free, values, ANCHORS, [t for t in terms if t.name in pool])
    current = {'gyro_bias', 'gyro_scale_factor', 'los_oscillation'}
    [change] = structural_changes(models, current)
    assert (change['action'], change['term'], change['effect']) == ('replace', 'gyro_scale_factor,los_oscillation',
                                                                   'gyro_axis_swap')
    assert change['expected_delta_bic'] > 6.0
    questioned = {entry['term']: entry for entry in model_terms(models, current)}
    [rival] = questioned['gyro_scale_factor']['rivals']
    assert rival['effect'] == 'gyro_axis_swap' and rival['shared_fraction'] > 0.99
