"""compare.pipeline: one comparison for every source, run here on a linear fake source that implements the protocol.

The fake's rows are in units of their noise; each catalogue effect it knows adds fixed random columns times its
parameters (so a fit is one linear solve and every answer is known): the truth holds gyro_bias and
gyro_scale_factor, heading_error's column is a mix of gyro_bias's (absorbed by it), accelerometer_bias is an
independent shape the truth lacks, timestamp_offset is one the fake cannot see.
"""

import numpy as np
import pytest

from sofia_ros.analysis.ranking import CandidateTerm, linear_fit
from sofia_ros.compare.diagnostics import Diagnostics
from sofia_ros.compare.fit import free_parameters
from sofia_ros.compare.pipeline import Judgement, LinearizedCandidate, WhitenedFit, run_comparison, switched_on
from sofia_ros.config import parse_effect_config
from sofia_ros.effects import resolve_params
from sofia_ros.measurements.compare import compare_measurement_set
from sofia_ros.measurements.validate import load_measurement_set

ROWS = 300
RNG = np.random.default_rng(26)
BIAS_COLUMNS = 50.0 * RNG.normal(size=(ROWS, 3))
COLUMNS = {
    'gyro_bias': BIAS_COLUMNS,
    'gyro_scale_factor': 0.01 * RNG.normal(size=(ROWS, 3)),
    'heading_error': BIAS_COLUMNS @ np.array([[0.3], [-0.2], [0.1]]),
    'accelerometer_bias': 0.1 * RNG.normal(size=(ROWS, 3)),
}
TRUTH = {name: resolve_params(name, {}) for name in ('gyro_bias', 'gyro_scale_factor')}
UNSEEN = {'timestamp_offset': 'the fake source has no clock'}
CANDIDATES = ('gyro_scale_factor', 'accelerometer_bias', 'heading_error', 'timestamp_offset')


def _predicted(effects):
    """The fake's prediction: each known effect's columns times its parameters (free_parameters order)."""
    total = np.zeros(ROWS)
    for name, params in effects.items():
        if name in COLUMNS:
            total += COLUMNS[name] @ np.array([params[p.name] for p in free_parameters([name])])
    return total


MEASURED = _predicted(TRUTH) + RNG.normal(size=ROWS)


class FakeSource:
    """A linear ComparisonSource: one observable, 'fake.x', its floor the unit noise."""

    noun = 'fake'
    observable_keys = ('rms_arcsec', 'floor_arcsec', 'ratio', 'explained', 'structure')
    hidden_reason = None
    model_source = 'fake-model.yaml'

    def __init__(self, model):
        self.model = model

    @staticmethod
    def beyond_floor(entry):
        return entry['ratio'] > 1.2

    def ledger_terms(self):
        return [name for name in self.model.effects if name in self.model.fitted]

    def ledger_start(self, previous, term):
        if previous is None:
            return {name: dict(params) for name, params in self.model.effects.items() if name not in self.model.fitted}
        return {**previous.effects, term: dict(self.model.effects[term])}

    def given_start(self):
        # the fake's fit is linear: one minimum, whatever it starts from
        return None

    def start_of(self, fit):
        return None

    def moved_start(self, fit, nuisance_change):
        return None

    def fit(self, effects, free, start):
        values = np.array([effects[p.effect][p.name] for p in free], dtype=float)
        residual = MEASURED - _predicted(effects)
        jacobian = np.column_stack([COLUMNS[p.effect][:, [q.name for q in free_parameters([p.effect])].index(p.name)]
                                    for p in free]) if free else np.zeros((ROWS, 0))
        solved = linear_fit(residual, jacobian, [p.label for p in free])
        fitted = {name: dict(params) for name, params in effects.items()}
        for parameter, value in zip(free, values + solved.step):
            fitted[parameter.effect][parameter.name] = float(value)
        return WhitenedFit(fitted, tuple(free), values + solved.step, solved.sigma, solved.correlation,
                           residual - jacobian @ solved.step, jacobian)

    def chain_step(self, term, effects, free, start, *, whole=False):
        fit = self.fit(effects, free, start)
        return fit, self.ledger_row(term, fit)

    def ledger_row(self, term, fit):
        return {'term': term or 'fixed effects only', 'residual_rms_arcsec': self.residual_rms(fit), 'bic': fit.bic}

    def residual_rms(self, fit):
        return {'total': float(np.sqrt(np.mean(fit.whitened ** 2)))}

    def rms_after(self, fit):
        return {'rms_after_arcsec': self.residual_rms(fit)['total']}

    def ranking_problem(self, fit):
        return fit.whitened, fit.jacobian, 0

    def judge_fit(self, fit):
        rms = self.residual_rms(fit)['total']
        entry = {'rms_arcsec': rms, 'floor_arcsec': 1.0, 'ratio': rms, 'structure': []}
        entry['explained'] = not self.beyond_floor(entry)
        return Judgement(Diagnostics({'fake.x': entry}, [], [], 0), [])

    def candidate_names(self, names, judgement):
        return names

    def linearize(self, fit, names):
        out = []
        for name in names:
            if name in UNSEEN:
                continue
            free, start, switched = switched_on(fit.effects, name)
            term = CandidateTerm(name, tuple(p.name for p in free), start, COLUMNS[name], np.zeros(ROWS))
            out.append(LinearizedCandidate(term, free, switched))
        return out, {name: UNSEEN[name] for name in names if name in UNSEEN}

    def extra_document(self, outcome, progress):
        return {'fake': True}


def _model(*fitted):
    effects = ', '.join(f'{name}: {{fit: true}}' for name in fitted)
    return parse_effect_config(f'effects: {{{effects}}}', 'fake-model.yaml')


def _compare(model):
    return run_comparison(FakeSource(model), model.effects, candidate_names=CANDIDATES)


@pytest.fixture(scope='module')
def lacking_the_scale_factor():
    return _compare(_model('gyro_bias')).document


def test_the_ledger_fits_the_fixed_effects_then_each_term(lacking_the_scale_factor):
    document = lacking_the_scale_factor
    assert [row['term'] for row in document['ledger']] == ['fixed effects only', 'gyro_bias']
    assert document['ledger'][1]['bic'] < document['ledger'][0]['bic']
    terms = {term['param']: term for term in document['terms']}
    assert set(terms) == {'el_deg_per_h', 'xel_deg_per_h', 'los_deg_per_h'}
    assert document['fake'] is True and document['seconds']['total'] >= 0.0


def test_the_missing_effect_ranks_first_refitted_at_its_truth(lacking_the_scale_factor):
    document = lacking_the_scale_factor
    best = document['candidates'][0]
    assert best['effect'] == 'gyro_scale_factor' and best['refined'] and best['delta_bic'] > 100.0
    for name, value in best['params'].items():
        assert value == pytest.approx(TRUTH['gyro_scale_factor'][name], abs=4.0 * best['sigma'][name])
    assert best['rms_after_arcsec'] == pytest.approx(1.0, abs=0.15)
    second = next(c for c in document['candidates'] if c['effect'] == 'accelerometer_bias')
    assert second['detectable'] and second['delta_bic'] < 6.0 and not second['refined']


def test_an_absorbed_candidate_is_degenerate_with_the_term_and_an_unseen_one_says_why(lacking_the_scale_factor):
    document = lacking_the_scale_factor
    hidden = {c['effect']: c for c in document['candidates'] if not c['detectable']}
    assert hidden['heading_error']['reason'] == 'absorbed by gyro_bias: this fake cannot tell them apart'
    assert hidden['timestamp_offset']['reason'] == UNSEEN['timestamp_offset']
    assert ['gyro_bias', 'heading_error'] in document['degenerate']
    assert document['unobservable'] == ['heading_error', 'timestamp_offset']


def test_the_verdict_names_the_effect_and_the_command(lacking_the_scale_factor):
    verdict = lacking_the_scale_factor['verdict']
    assert verdict['status'] == 'missing_effect'
    assert verdict['next'] == {'action': 'add', 'effect': 'gyro_scale_factor', 'term': None,
                               'command': 'sofia model add gyro_scale_factor --model fake-model.yaml'}
    assert verdict['after_best'] == {'effect': 'gyro_scale_factor', 'unexplained': [], 'inconsistent_terms': []}
    assert not verdict['observables']['fake.x']['explained']
    assert 'with it every observable is explained' in verdict['text']
    [term] = lacking_the_scale_factor['model_terms']
    assert term['term'] == 'gyro_bias' and term['pays']


class StartsWatched(FakeSource):
    """The fake source, the values each fit starts from kept."""

    def __init__(self, model):
        super().__init__(model)
        self.starts = []

    def fit(self, effects, free, start):
        self.starts.append({p.label: effects[p.effect][p.name] for p in free})
        return super().fit(effects, free, start)


def test_a_linear_sources_refit_starts_at_its_own_answer():
    # The fake is linear and its model fitted exactly: the joint linearized step (the candidate's values and the
    # model's terms moved beside them, RankedCandidate.base_change) is the refit's answer, so it starts there.
    source = StartsWatched(_model('gyro_bias'))
    document = run_comparison(source, source.model.effects, candidate_names=CANDIDATES).document
    refit = next(c for c in document['candidates'] if c['effect'] == 'gyro_scale_factor')
    labels = [p.label for p in free_parameters(['gyro_bias', 'gyro_scale_factor'])]
    started = next(start for start in source.starts if list(start) == labels)
    joint = np.linalg.lstsq(np.column_stack([COLUMNS['gyro_bias'], COLUMNS['gyro_scale_factor']]), MEASURED,
                            rcond=None)[0]
    np.testing.assert_allclose([started[label] for label in labels], joint, rtol=1e-9, atol=1e-12)
    assert [refit['params'][name] for name in ('el_ppm', 'xel_ppm', 'los_ppm')] == pytest.approx(joint[3:], rel=1e-9)


def test_the_model_of_the_truth_is_explained_with_nothing_to_do():
    document = _compare(_model('gyro_bias', 'gyro_scale_factor')).document
    assert document['verdict']['status'] == 'explained'
    assert document['verdict']['headline'] == 'explained: nothing to do'
    assert all(c['delta_bic'] < 6.0 for c in document['candidates'])
    assert document['model_change'] is None and all(term['pays'] for term in document['model_terms'])


def test_a_term_the_data_do_not_need_is_questioned_and_its_removal_proposed():
    document = _compare(_model('gyro_bias', 'gyro_scale_factor', 'accelerometer_bias')).document
    useless = next(term for term in document['model_terms'] if term['term'] == 'accelerometer_bias')
    assert not useless['pays']
    change = document['model_change']
    assert (change['action'], change['term']) == ('remove', 'accelerometer_bias') and change['delta_bic'] >= 6.0
    assert document['verdict']['next']['command'] == 'sofia model remove accelerometer_bias --model fake-model.yaml'


def test_a_set_of_rates_states_its_gain_in_arcsec_per_s():
    """A set with rate observables only (Table 5.7's means) has no angle RMS: the verdict's gain is in "/s."""
    measurement_set = load_measurement_set('data/thesis-2004/edwards-earth-rate-2007.yaml')
    document = compare_measurement_set(measurement_set, parse_effect_config('effects: {earth_rotation: {}}',
                                                                            'bare.yaml')).document
    assert document['residual_rms_arcsec'] == {}
    assert document['verdict']['next']['effect'] == 'gyro_bias'
    assert 'missing effect gyro_bias (RMS 0.4095"/s -> 0.0113"/s)' in document['verdict']['text']
    assert document['model_terms'] == [] and document['model_change'] is None
