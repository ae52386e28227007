"""`sofia design` (issue 28, docs/design.md): the separation formula against closed forms, the choice of elements,
the command's refusals, and the prediction on the session's gyro_axis_swap bag."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from sofia_ros.cli import main
from sofia_ros.design.elements import Element, Hypothesis, choose_elements, predict
from sofia_ros.design.separation import (Information, expected_delta_bic, fitted_values, noncentrality,
                                         profiled_gram, sigma_of)
from sofia_ros.errors import InvalidArgumentError

ROOT = Path(__file__).resolve().parents[1]
NOMINAL_MODEL = ROOT / 'config' / 'model' / 'nominal.yaml'
LABELS = ('m.0', 'a.0', 'b.0')


def _information(nuisance: np.ndarray, columns: np.ndarray, residual: np.ndarray | None = None) -> Information:
    """The profiled information of a dense linear problem with nuisance columns."""
    residual = np.zeros(len(columns)) if residual is None else residual
    gram = profiled_gram(nuisance.T @ nuisance, nuisance.T @ columns, columns.T @ columns)
    projector = nuisance @ np.linalg.pinv(nuisance)
    gradient = columns.T @ (residual - projector @ residual)
    return Information(LABELS, gram, gradient, len(columns))


def _problem(seed: int = 0, rows: int = 400):
    rng = np.random.default_rng(seed)
    nuisance = rng.normal(size=(rows, 4))
    shared = rng.normal(size=(rows, 1))
    first = rng.normal(size=(rows, 1))
    # The rival mimics the first member closely: the pair a campaign can hardly tell apart.
    second = 0.95 * first + 0.3 * rng.normal(size=(rows, 1))
    return nuisance, np.hstack([shared, first, second])


def test_noncentrality_is_what_the_rival_leaves_of_the_true_signature():
    nuisance, columns = _problem()
    theta = 2.5
    signal = columns[:, 1] * theta
    rival = np.hstack([nuisance, columns[:, [0, 2]]])
    left = signal - rival @ np.linalg.lstsq(rival, signal, rcond=None)[0]
    assert noncentrality(_information(nuisance, columns), ['a.0'], np.array([theta]), ['b.0'], ['m.0']) == \
        pytest.approx(float(left @ left), rel=1e-9)


def test_orthogonal_members_separate_by_the_whole_signature():
    rows = 100
    columns = np.zeros((rows, 3))
    columns[:50, 1], columns[50:, 2], columns[:, 0] = 1.0, 1.0, np.r_[np.zeros(50), np.zeros(50)]
    information = _information(np.ones((rows, 1)) * 0.0, columns)
    # |J_A theta|^2 = 50 theta^2; with a zero nuisance and shared column, nothing of it is absorbed.
    assert noncentrality(information, ['a.0'], np.array([0.2]), ['b.0'], ['m.0']) == pytest.approx(50 * 0.04)


def test_blocks_with_their_own_nuisance_add():
    nuisance, columns = _problem(1, 200)
    other_nuisance, other_columns = _problem(2, 300)
    stacked_nuisance = np.block([[nuisance, np.zeros((200, 4))], [np.zeros((300, 4)), other_nuisance]])
    together = _information(stacked_nuisance, np.vstack([columns, other_columns]))
    summed = _information(nuisance, columns) + _information(other_nuisance, other_columns)
    np.testing.assert_allclose(summed.gram, together.gram, rtol=1e-9, atol=1e-9)
    assert summed.rows == 500


def test_expected_delta_bic_matches_simulated_fits():
    """The mean BIC(rival) - BIC(true) of many noisy draws (compare's BIC, n ln(RSS/n) + k ln n) against the formula."""
    nuisance, columns = _problem(3, 600)
    theta = 0.4
    rng = np.random.default_rng(4)
    true_design, rival_design = np.hstack([nuisance, columns[:, [0, 1]]]), np.hstack([nuisance, columns[:, [0, 2]]])
    extra_rival = np.hstack([rival_design, rng.normal(size=(600, 1))])  # a rival with one parameter more
    differences = {1: [], 2: []}
    for _ in range(300):
        data = columns[:, 1] * theta + rng.normal(size=600)
        rss = {}
        for key, design in (('true', true_design), ('rival', rival_design), ('extra', extra_rival)):
            left = data - design @ np.linalg.lstsq(design, data, rcond=None)[0]
            rss[key] = float(left @ left)
        bic = {key: 600 * np.log(value / 600) for key, value in rss.items()}
        differences[1].append(bic['rival'] - bic['true'])
        differences[2].append(bic['extra'] + np.log(600) - bic['true'])
    information = _information(nuisance, columns)
    lam = noncentrality(information, ['a.0'], np.array([theta]), ['b.0'], ['m.0'])
    assert np.mean(differences[1]) == pytest.approx(expected_delta_bic(lam, 1, 1, 600), abs=1.0)
    assert expected_delta_bic(lam, 1, 2, 600) - expected_delta_bic(lam, 1, 1, 600) == pytest.approx(np.log(600) - 1)
    # The extra parameter absorbs a little of the signature: the mean lies at or just below the formula's.
    assert np.mean(differences[2]) == pytest.approx(expected_delta_bic(lam, 1, 2, 600), abs=1.5)


def test_sigma_and_fitted_values_are_those_of_least_squares():
    nuisance, columns = _problem(5)
    rng = np.random.default_rng(6)
    data = columns[:, [0, 1]] @ np.array([0.3, -1.2]) + rng.normal(size=len(columns))
    information = _information(nuisance, columns, data)
    design = np.hstack([nuisance, columns[:, [0, 1]]])
    solution = np.linalg.lstsq(design, data, rcond=None)[0]
    np.testing.assert_allclose(fitted_values(information, ['m.0', 'a.0']), solution[-2:], rtol=1e-9)
    covariance = np.linalg.inv(design.T @ design)
    np.testing.assert_allclose(sigma_of(information, ['m.0', 'a.0'], 2.0), np.sqrt(2.0 * np.diag(covariance))[-2:],
                               rtol=1e-9)


def _element_blocks():
    """Three elements: one that adds nothing, a long one and a short one that separate the members."""
    nuisance, columns = _problem(7, 300)
    base = _information(nuisance, columns)
    useless = Information(LABELS, np.diag([1.0, 0.0, 0.0]), np.zeros(3), 50)

    def separating(weight):
        gram = np.zeros((3, 3))
        gram[1, 1] = gram[2, 2] = weight
        return Information(LABELS, gram, np.zeros(3), 50)

    return base, [useless, separating(4000.0), separating(3000.0)], [30.0, 200.0, 90.0]


def test_the_fewest_elements_then_the_shortest_reach_the_target():
    base, elements, flight_s = _element_blocks()
    first, second = Hypothesis('a', ('a.0',), np.array([0.1])), Hypothesis('b', ('b.0',), np.array([0.1]))
    choice = choose_elements(base, elements, flight_s, ['m.0'], first, second, 1.0, target=20.0, budget_s=250.0)
    assert choice.reached and choice.indices == (2,) and choice.flight_s == 90.0
    assert predict(base, ['m.0'], first, second, 1.0).weakest < 20.0 <= choice.prediction.weakest


def test_a_target_out_of_reach_gives_the_best_within_the_budget():
    base, elements, flight_s = _element_blocks()
    first, second = Hypothesis('a', ('a.0',), np.array([0.01])), Hypothesis('b', ('b.0',), np.array([0.01]))
    choice = choose_elements(base, elements, flight_s, ['m.0'], first, second, 1.0, target=1e6, budget_s=100.0)
    assert not choice.reached and choice.flight_s <= 100.0


def test_a_budget_below_the_shortest_element_is_refused():
    base, elements, flight_s = _element_blocks()
    member = Hypothesis('a', ('a.0',), np.array([1.0]))
    with pytest.raises(InvalidArgumentError, match=r'budget of 10 s is below the shortest element \(30 s\)'):
        choose_elements(base, elements, flight_s, ['m.0'], member, member, 1.0, target=20.0, budget_s=10.0)


# --- the command's refusals: one line, exit 2, nothing written --------------------------------------------------


def _refused(capsys, tmp_path, argv, match):
    code = main(['design', *argv])
    err = capsys.readouterr().err
    assert code == 2 and len(err.strip().splitlines()) == 1 and 'Traceback' not in err, err
    assert match in err, err
    assert not (tmp_path / 'plan.yaml').exists()
    return err


@pytest.fixture
def plan_only_bag(tmp_path):
    """A folder with only the plan.yaml a run records: enough for the refusals before anything is read."""
    bag = tmp_path / 'bag'
    bag.mkdir()
    shutil.copy(ROOT / 'config' / 'plans' / 'alignment-reduced.yaml', bag / 'plan.yaml')
    return bag


@pytest.mark.parametrize('between, match', [
    ('hipo_fiducial_error,no_such_effect', 'no_such_effect'),
    ('hipo_fiducial_error', 'give two members'),
    ('gyro_scale_factor,gyro_scale_factor+gyro_axis_swap', 'the members share gyro_scale_factor'),
])
def test_a_bad_competing_set_is_refused(capsys, tmp_path, plan_only_bag, between, match):
    _refused(capsys, tmp_path, [str(plan_only_bag), '--model', str(NOMINAL_MODEL), '--between', between,
                                '--plan-out', str(tmp_path / 'plan.yaml')], match)


def test_a_member_the_model_has_is_refused(capsys, tmp_path, plan_only_bag):
    _refused(capsys, tmp_path, [str(plan_only_bag), '--model', str(NOMINAL_MODEL), '--between',
                                'gyro_axis_swap,gyro_bias', '--plan-out', str(tmp_path / 'plan.yaml')],
             'gyro_bias is already in the model')


def test_a_bag_without_its_plan_takes_one_given(capsys, tmp_path, plan_only_bag):
    (plan_only_bag / 'plan.yaml').unlink()
    shutil.copy(ROOT / 'config' / 'plans' / 'star-hop-reduced.yaml', tmp_path / 'given.yaml')
    # The given plan is read (and, a star hop's, refused): not the bag's missing plan.yaml.
    _refused(capsys, tmp_path, [str(plan_only_bag), '--model', str(NOMINAL_MODEL), '--between',
                                'gyro_axis_swap,gyro_scale_factor', '--plan', str(tmp_path / 'given.yaml')],
             'plans alignment campaigns')


def test_a_star_hop_bag_is_refused(capsys, tmp_path, plan_only_bag):
    shutil.copy(ROOT / 'config' / 'plans' / 'star-hop-reduced.yaml', plan_only_bag / 'plan.yaml')
    _refused(capsys, tmp_path, [str(plan_only_bag), '--model', str(NOMINAL_MODEL), '--between',
                                'gyro_axis_swap,gyro_scale_factor', '--plan-out', str(tmp_path / 'plan.yaml')],
             'plans alignment campaigns')


@pytest.mark.parametrize('document, match', [
    ('[1, 2]', 'not a comparison'),
    ('{"bag": "b", "competing": []}', 'states no competing set'),
    ('{"model": "m.yaml"}', 'not the JSON of `sofia compare` on a bag'),
    ('{"bag": "b", "competing": [', 'is not JSON'),
    ('{"bag": "b", "competing": [{"effects": [1, 2]}]}', 'does not list two effects'),
    ('{"bag": "b", "competing": ["x"]}', 'does not list two effects'),
])
def test_a_bad_comparison_json_is_refused(capsys, tmp_path, document, match):
    source = tmp_path / 'compare.json'
    source.write_text(document)
    _refused(capsys, tmp_path, [str(source), '--plan-out', str(tmp_path / 'plan.yaml')], match)


def test_a_second_competing_set_that_is_not_there_is_refused(capsys, tmp_path):
    source = tmp_path / 'compare.json'
    source.write_text(json.dumps({'bag': 'b', 'competing': [{'effects': ['gyro_axis_swap', 'gyro_scale_factor']}]}))
    _refused(capsys, tmp_path, [str(source), '--set', '2'], 'states 1 competing set(s)')


def test_a_check_against_a_json_that_is_no_design_is_refused(capsys, tmp_path):
    prediction = tmp_path / 'design.json'
    prediction.write_text(json.dumps({'bag': 'b', 'competing': []}))
    _refused(capsys, tmp_path, ['--check', str(tmp_path), '--prediction', str(prediction)],
             'is not the JSON of `sofia design`')


@pytest.mark.parametrize('argv, match', [
    (['--check', 'new_bag'], 'needs --prediction'),
    (['--prediction', 'design.json'], '--prediction goes with --check'),
    (['--budget-s', '0'], '--budget-s'),
])
def test_bad_options_are_refused(capsys, tmp_path, plan_only_bag, argv, match):
    _refused(capsys, tmp_path, [str(plan_only_bag), *argv], match)


def test_a_plan_out_that_is_a_directory_is_refused(capsys, tmp_path, plan_only_bag):
    _refused(capsys, tmp_path, [str(plan_only_bag), '--model', str(NOMINAL_MODEL), '--between',
                                'gyro_axis_swap,gyro_scale_factor', '--plan-out', str(tmp_path)], 'is a directory')


def test_an_already_separated_set_says_so_and_writes_no_plan(capsys, tmp_path, plan_only_bag, monkeypatch):
    """Exit 0 and no plan: the prediction (stubbed here; its machinery is tested below) finds nothing to add."""
    import sofia_ros.compare.observations as observations
    import sofia_ros.design.cli as design_cli
    import sofia_ros.design.run as design_run

    class Stub:
        calibration_result = 'elements: []\n'
        initial_time_s = 0.0

        class centroids:  # noqa: N801 (the attribute the command reads)
            stamp_s = np.array([0.0, 800.0])

    document = {'bag': str(plan_only_bag), 'model': str(NOMINAL_MODEL), 'members': ['a', 'b'], 'shared': [],
                'flight_s': 800.0, 'budget_s': 240.0, 'target_delta_bic': 20.0, 'sizes': {'a': {}, 'b': {}},
                'observed_delta_bic': {'a': 50.0, 'b': 10.0}, 'before': {'a': 40.0, 'b': 35.0}, 'elements': [],
                'status': 'already_separated', 'chosen': [], 'chosen_flight_s': 0.0, 'flight_share': 0.0,
                'predicted': {'a': 40.0, 'b': 35.0}, 'sigma_before': {}, 'sigma_after': {}, 'skipped': []}
    monkeypatch.setattr(design_cli, '_library_bag', lambda elements, plan, progress: plan_only_bag)
    monkeypatch.setattr(observations, 'read_observations', lambda path: Stub())
    monkeypatch.setattr(design_run, 'design_plan', lambda *args, **kwargs: dict(document))
    code = main(['design', str(plan_only_bag), '--model', str(NOMINAL_MODEL), '--between',
                 'gyro_axis_swap,gyro_scale_factor', '--plan-out', str(tmp_path / 'plan.yaml'), '--quiet'])
    out = capsys.readouterr().out
    assert code == 0 and 'already separated' in out and 'no plan is needed' in out
    assert not (tmp_path / 'plan.yaml').exists()


# --- the prediction on a real bag -----------------------------------------------------------------------------


def test_the_prediction_on_the_session_bag(campaign_bags):
    """The session's gyro_axis_swap bag as the old bag and, cut in time windows, as the library: the members' sizes are
    the truth's, they are not separated (issue 25's tie), and each window adds what its rows add."""
    from sofia_ros.compare.observations import read_observations
    from sofia_ros.config import load_effect_config
    from sofia_ros.design.run import design_plan

    observations = read_observations(campaign_bags.reduced_alignment(effect='gyro_axis_swap'))
    stamps = observations.centroids.stamp_s
    middle = float(np.median(stamps))
    windows = [(Element('first half', {'hold': {'duration_s': 60.0}}), float(stamps.min()), middle),
               (Element('second half', {'hold': {'duration_s': 60.0}}), middle, float(stamps.max()) + 1.0)]
    document = design_plan(observations, observations, windows, ['skipped one'], load_effect_config(NOMINAL_MODEL),
                           [['gyro_axis_swap'], ['gyro_scale_factor']], flight_s=800.0, budget_s=400.0, target=20.0)
    assert document['sizes']['gyro_axis_swap']['gyro_axis_swap.scale_difference_ppm'] == pytest.approx(400.0, rel=0.1)
    assert document['status'] in {'designed', 'not_reached'} and document['skipped'] == ['skipped one']
    assert document['before']['gyro_axis_swap'] < 20.0
    assert [entry['name'] for entry in document['elements']] == ['first half', 'second half']
    json.dumps(document)  # JSON-ready as --json writes it


def test_flown_elements_reads_the_windows_and_names_the_skipped():
    from sofia_ros.design.run import flown_elements
    from sofia_ros.errors import BagError

    library = (Element('one', {}), Element('two', {}), Element('three', {}))
    calibration = ('elements:\n- {index: 1, kind: maneuvers, start_s: 10.0, end_s: 50.0}\n'
                   '- {index: 3, kind: hold, start_s: 50.0, end_s: 120.5}\n')
    windows, skipped = flown_elements(calibration, library)
    assert [(element.name, start, end) for element, start, end in windows] == [('one', 10.0, 50.0),
                                                                               ('three', 50.0, 120.5)]
    assert skipped == ['two']
    with pytest.raises(BagError, match='no calibration result; delete it so that it is flown again'):
        flown_elements(None, library)
