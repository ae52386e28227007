"""Competing explanations (issue 25): shared fractions, competing sets, the refits and the preferred member."""

import numpy as np
import pytest

from sofia_ros.analysis.ranking import (COMPETING_DELTA_BIC, COMPETING_FRACTION, SHARED_FRACTION, CandidateTerm,
                                        competing_sets, rank_candidates, shared_fraction)
from sofia_ros.compare.verdict import HEADLINE_CHARACTERS, headline, next_step
from sofia_ros.compare.competing import (REFINED_CANDIDATES, REFINED_PHYSICAL, competing_document, contenders,
                                         preferred_best, refit_order)

ROWS = 4000


def _noise(seed=1):
    return np.random.default_rng(seed).standard_normal(ROWS)


def _shape(seed):
    return np.random.default_rng(seed).standard_normal(ROWS)


def test_the_shared_fraction_of_one_signature_with_itself_is_one_and_with_an_orthogonal_one_zero():
    first = _shape(2)
    second = _shape(3)
    second -= (second @ first) / (first @ first) * first
    residual = first + second
    assert shared_fraction(residual, first, 2.0 * first) == pytest.approx(1.0)
    assert shared_fraction(residual, first, second) == pytest.approx(0.0, abs=1e-12)


def test_the_shared_fraction_of_a_half_overlap():
    # b = (a + c)/sqrt(2) with a, c orthonormal: b's drop is (r.b)^2; a removes half of it.
    a = _shape(4)
    a /= np.linalg.norm(a)
    c = _shape(5)
    c -= (c @ a) * a
    c /= np.linalg.norm(c)
    b = (a + c) / np.sqrt(2.0)
    residual = a
    # Drops: a 1, b 1/2, both together 1 (b adds nothing a does not): shared = (1 + 1/2 - 1) / (1/2) = 1.
    assert shared_fraction(residual, a, b) == pytest.approx(1.0)
    residual = a + c
    # Drops: a 1, b 2, both 2: shared = (1 + 2 - 2) / 1 = 1 (a's drop lies wholly inside b's).
    assert shared_fraction(residual, a, b) == pytest.approx(1.0)
    residual = a - c
    # b sees nothing of a - c: its drop is 0, the share undefined and stated as 0.
    assert shared_fraction(residual, a, b) == pytest.approx(0.0, abs=1e-12)


def _ranked(scale_second=1.0, second_shape=None, noise=1.0):
    """The residual holds 0.2 x shape 10; A is that shape, B nearly it (or another), C an unrelated one."""
    shape = _shape(10)
    residual = 0.2 * shape + noise * _noise()
    base = _shape(11)[:, np.newaxis]
    second = scale_second * shape + 0.05 * _shape(12) if second_shape is None else second_shape
    terms = [CandidateTerm('physical_a', ('p',), np.zeros(1), shape[:, np.newaxis]),
             CandidateTerm('empirical:fpi.x:time:poly1', ('q',), np.zeros(1), second[:, np.newaxis]),
             CandidateTerm('unrelated', ('r',), np.zeros(1), _shape(13)[:, np.newaxis])]
    return rank_candidates(residual, base, terms)


def test_two_shapes_of_one_residual_compete_and_physics_comes_first():
    ranked = _ranked()
    scores = {c.name: c.delta_bic for c in ranked}
    assert scores['physical_a'] > 100 and scores['empirical:fpi.x:time:poly1'] > 100
    sets = competing_sets(ranked, preferred=lambda name: not name.startswith('empirical:'))
    assert len(sets) == 1
    assert sets[0].effects == ('physical_a', 'empirical:fpi.x:time:poly1')
    assert sets[0].shared_fraction >= SHARED_FRACTION
    # The empirical shape may score a little higher or lower: physics is listed first either way.
    flipped = competing_sets(ranked, {'empirical:fpi.x:time:poly1': scores['physical_a'] + 5.0},
                             preferred=lambda name: not name.startswith('empirical:'))
    assert flipped[0].effects[0] == 'physical_a'


def test_a_gap_beyond_the_margin_is_not_a_competition():
    ranked = _ranked()
    scores = {c.name: c.delta_bic for c in ranked}
    top = scores['physical_a']
    margin = max(COMPETING_DELTA_BIC, COMPETING_FRACTION * top)
    assert competing_sets(ranked, {'empirical:fpi.x:time:poly1': top - 1.01 * margin}) == []
    assert len(competing_sets(ranked, {'empirical:fpi.x:time:poly1': top - 0.99 * margin})) == 1


def test_independent_shapes_do_not_compete_however_close_their_scores():
    # B explains a shape of its own that the residual holds as strongly as A's.
    shape, other = _shape(10), _shape(20)
    residual = 0.2 * shape + 0.2 * other + _noise()
    terms = [CandidateTerm('a', ('p',), np.zeros(1), shape[:, np.newaxis]),
             CandidateTerm('b', ('q',), np.zeros(1), other[:, np.newaxis])]
    ranked = rank_candidates(residual, _shape(11)[:, np.newaxis], terms)
    scores = {c.name: c.delta_bic for c in ranked}
    assert min(scores.values()) > 50
    shared = next(c for c in ranked if c.name == 'a').shared_with['b']
    assert shared < 0.05
    assert competing_sets(ranked, {'b': scores['a']}) == []


def test_the_verdict_takes_the_member_that_explains_then_physics():
    ranked = _ranked()
    sets = competing_sets(ranked, preferred=lambda name: not name.startswith('empirical:'))
    scores = {'physical_a': 1000.0, 'empirical:fpi.x:time:poly1': 1030.0, 'unrelated': 2.0}
    names = contenders(['physical_a', 'empirical:fpi.x:time:poly1', 'unrelated'], scores, sets)
    assert names == ['physical_a', 'empirical:fpi.x:time:poly1']
    both = {name: {'status': 'explained'} for name in names}
    assert preferred_best(names, scores, both) == 'physical_a'
    only_shape = {'physical_a': {'status': 'not explained'}, 'empirical:fpi.x:time:poly1': {'status': 'explained'}}
    assert preferred_best(names, scores, only_shape) == 'empirical:fpi.x:time:poly1'
    # Not refitted, the physical member cannot be taken; outside any set the best delta-BIC is alone.
    assert contenders(['empirical:fpi.x:time:poly1'], scores, sets) == ['empirical:fpi.x:time:poly1']
    assert contenders(['unrelated'], scores, sets) == ['unrelated']
    assert contenders([], scores, sets) == [] and preferred_best([], scores, {}) is None


def test_physical_candidates_behind_empirical_shapes_are_refitted_too():
    class Candidate:
        def __init__(self, name, delta_bic):
            self.name, self.delta_bic, self.significant = name, delta_bic, delta_bic >= 6

    ranked = [Candidate(f'empirical:hipo.x:detector_y:poly{i}', 9000 - i) for i in range(1, 5)]
    ranked += [Candidate('timestamp_offset', 7500), Candidate('tracker_drift', 7000), Candidate('seeing_x', 6500),
               Candidate('weak', 3)]
    names = [c.name for c in refit_order(ranked)]
    assert names[:REFINED_CANDIDATES] == [c.name for c in ranked[:REFINED_CANDIDATES]]
    assert names[REFINED_CANDIDATES:] == ['timestamp_offset', 'tracker_drift'][:REFINED_PHYSICAL]


def test_the_document_says_what_each_member_leaves_and_where_they_differ():
    ranked = _ranked()
    sets = competing_sets(ranked, preferred=lambda name: not name.startswith('empirical:'))
    after = {'physical_a': {'status': 'explained', 'unexplained': [], 'ratios': {'fpi.x': 1.0, 'hipo.x': 1.02}},
             'empirical:fpi.x:time:poly1': {'status': 'not explained', 'unexplained': ['fpi.x'],
                                            'ratios': {'fpi.x': 1.8, 'hipo.x': 1.03}}}
    [entry] = competing_document(sets, after)
    assert entry['effects'] == ['physical_a', 'empirical:fpi.x:time:poly1']
    assert entry['verdict_with_each'] == {'physical_a': 'explained', 'empirical:fpi.x:time:poly1': 'not explained'}
    assert entry['separable_by'] == ['fpi.x']
    assert set(entry['delta_bic']) == set(entry['effects'])


@pytest.mark.parametrize('status, action, names', [
    ('explained', 'none', {}),
    ('missing_effect', 'add', {'effect': 'timestamp_offset'}),
    ('missing_effect', 'add', {'effect': 'empirical:hipo.y:detector_y:poly3@59.82..981.4'}),
    ('explained', 'remove', {'term': 'imager_rotation_of_field'}),
    ('missing_effect', 'replace', {'term': 'imager_boresight_offset,imager_rotation_of_field',
                                   'effect': 'hipo_fiducial_error'}),
    ('unexplained', 'plugin', {'kind': 'gyro'}),
])
@pytest.mark.parametrize('model', ['m.yaml', '/a/very/long/path/to/the/models/of/this/telescope/nominal-plus.yaml'])
def test_a_headline_is_short_and_ends_with_what_to_run(status, action, names, model):
    step = next_step(action, model, **names)
    line = headline(status, step)
    assert len(line) <= HEADLINE_CHARACTERS and line.startswith(f'{status}: ')
    if action == 'none':
        assert line.endswith('nothing to do') and step['command'] is None
    else:
        # The command whole where it fits; else its model file by name; else without --model (next.command has it).
        command = line.split(': ', 1)[1].split(': ')[-1]
        bare = step['command'].split(' --model ')[0]
        if len(f'{status}: {bare}') <= HEADLINE_CHARACTERS:
            assert command.startswith('sofia ') and step['command'].startswith(command.split(' --model ')[0])
        else:  # only names too long for any form are cut, visibly
            assert line.endswith('...') and bare.startswith(command[:-3])
        if len(f'{status}: {step["command"]}') <= HEADLINE_CHARACTERS:
            assert line.endswith(step['command'])
