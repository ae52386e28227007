"""`sofia atlas` truths with several effects hidden at once: the grid (explicit lists, seeded draws, controls), the
scoring of a final model against what was hidden, the rates and confusions, and one tiny grid run end to end."""

import json

import pyarrow.parquet as pq
import pytest

from sofia_ros.atlas.grid import (MAX_TASKS, VISIBLE_EFFECTS, draw_truths, grid_from_file, grid_from_lists,
                                  hidden_truth_text, truth_draws)
from sofia_ros.atlas.report import summarize, text_table, write_html
from sofia_ros.atlas.scoring import SCORES, confused_pairs, score_truth, stated_competitors, stated_pairs
from sofia_ros.atlas.stats import table_6_5_slice, truth_confusions, truth_misses, truth_rates
from sofia_ros.atlas.task import ROW_FIELDS
from sofia_ros.cli import main
from sofia_ros.config import parse_effect_config
from sofia_ros.errors import ConfigError, UnknownEffectError

BASE = dict(effects=[], sizes=[], campaigns=['alignment:reduced'], seeds=[1])
POOL = VISIBLE_EFFECTS['alignment']


def _truths(grid):
    return [task.hidden for task in grid.iter_tasks()]


# --- the grid -----------------------------------------------------------------------------------------------------

def test_draws_are_distinct_sets_of_k_effects_the_same_for_the_same_seed():
    drawn = draw_truths(POOL, 30, (2, 3), 2025)
    assert drawn == draw_truths(POOL, 30, (2, 3), 2025)
    assert drawn != draw_truths(POOL, 30, (2, 3), 2026)
    assert [len(truth) for truth in drawn] == [2, 3] * 15  # k cycles through the list
    assert len(set(drawn)) == 30 and all(list(truth) == sorted(set(truth)) for truth in drawn)
    assert all(set(truth) <= set(POOL) for truth in drawn)
    pairs = ((POOL[0], POOL[1]), (POOL[0], POOL[2]), (POOL[1], POOL[2]))
    assert sorted(draw_truths(POOL[:3], 3, (2,), 1)) == sorted(tuple(sorted(pair)) for pair in pairs)
    listed = ((POOL[0], POOL[1]),)
    assert listed[0] not in draw_truths(POOL[:3], 2, (2,), 1, listed)  # a truth listed is not drawn again


def test_a_grid_of_truths_draws_from_the_campaigns_visible_effects_less_the_models_and_flies_each_with_its_seed():
    grid = grid_from_lists(**BASE, truths=['tracker_drift+timestamp_offset', []],
                           draws=truth_draws(4, [2, 3], 7), controls=2, search_rounds=3)
    tasks = grid.tasks()
    assert grid.task_count() == len(tasks) == 2 + 4 + 2 and len({task.key for task in tasks}) == len(tasks)
    assert tasks[0].hidden == ('timestamp_offset', 'tracker_drift')
    assert tasks[0].effect == 'timestamp_offset+tracker_drift'
    assert [task.seed for task in tasks] == list(range(1, 9))  # truth i with seed 1 + i
    assert all(task.search_rounds == 3 and task.key.endswith(f'|truth{task.truth_index}') for task in tasks)
    drawn = [task.hidden for task in tasks if task.hidden and task.truth_index > 0]
    assert drawn == draw_truths(tuple(POOL), 4, (2, 3), 7, (('timestamp_offset', 'tracker_drift'), ()))
    controls = [task for task in tasks if not task.hidden]
    assert len(controls) == 3 and all(task.effect == 'none' and task.size == 0 for task in controls)
    # the controls are spread among the truths (a partial atlas has its share), the explicit one where it was listed
    assert [index for index, task in enumerate(tasks) if not task.hidden] == [1, 3, 7]
    assert grid.describe()['truths']['alignment:reduced'][0] == 'timestamp_offset+tracker_drift'


def test_a_truth_hides_each_of_its_effects_at_its_default():
    grid = grid_from_lists(**BASE, truths=['tracker_drift+timestamp_offset'])
    truth = parse_effect_config(hidden_truth_text(grid.truth, grid.tasks()[0].hidden, 1.0))
    assert set(truth.effects) == set(grid.truth.effects) | {'timestamp_offset', 'tracker_drift'}
    assert truth.effects['timestamp_offset']['offset_s'] == 1.0


def test_a_single_effect_grid_keeps_its_fingerprint_and_its_keys():
    grid = grid_from_lists(effects=['timestamp_offset'], sizes=[1], campaigns=['alignment:minimal'], seeds=[1])
    assert 'truths' not in grid.describe() and grid.tasks()[0].key == 'timestamp_offset|1|alignment|minimal|1'
    assert grid.tasks()[0].hidden == ('timestamp_offset',)


def test_a_grid_file_gives_the_grid_of_the_flags(tmp_path, capsys):
    path = tmp_path / 'grid.yaml'
    path.write_text('campaigns: [alignment:reduced]\nseeds: [1]\ntruths: [[timestamp_offset, tracker_drift], []]\n'
                    'draws: {count: 3, k: [2, 3], seed: 5}\ncontrols: 1\nsearch_rounds: 4\n')
    from_file = grid_from_file(path)
    from_lists = grid_from_lists(**BASE, truths=['timestamp_offset+tracker_drift', 'none'],
                                 draws=truth_draws(3, [2, 3], 5), controls=1, search_rounds=4)
    assert from_file.fingerprint() == from_lists.fingerprint()
    assert _truths(from_file) == _truths(from_lists)


@pytest.mark.parametrize('change, message', [
    ({'draws': truth_draws(2, [0], 1)}, r'draws: k = 0 is outside 1\.\.9'),
    ({'draws': truth_draws(2, [10], 1)}, r'draws: k = 10 is outside 1\.\.9 \(the 9 effects of the pool\)'),
    ({'draws': truth_draws(4, [2], 1, ['timestamp_offset', 'tracker_drift', 'gyro_scale_factor'])},
     '4 distinct sets of 2 effects asked from a pool of 3, which has only 3'),
    ({'draws': truth_draws(1, [2], 1, ['gyro_bias', 'tracker_drift'])}, "'gyro_bias' is a term of the model"),
    ({'truths': [['tracker_drift', 'tracker_drift']]}, 'names an effect twice'),
    ({'truths': [['seeing', 'tracker_drift']]}, "'seeing' is a noise process"),
    ({'truths': [7]}, 'give a list of effects, A\\+B'),
    ({'truths': ['tracker_drift'], 'search_rounds': 21}, r'search_rounds 21 must be an integer in 1\.\.20'),
    ({'effects': ['tracker_drift'], 'sizes': [1], 'search_rounds': 3}, 'search_rounds is for truths'),
    ({'controls': -1}, r'controls -1 must be an integer in 0\.\.'),
    ({'truths': ['tracker_drift'], 'controls': MAX_TASKS}, r'the grid is 10001 tasks \(10001 truths x 1 seeds\)'),
    ({'effects': ['tracker_drift'], 'sizes': [1, 2], 'controls': MAX_TASKS - 1},
     r'the grid is 10001 tasks \(1 effects x 2 sizes x 1 campaigns \+ 9999 truths, x 1 seeds\)'),
    ({'truths': ['tracker_drift'], 'seeds': [2**32 - 1], 'controls': 1}, 'is beyond the largest seed'),
])
def test_bad_truths_are_one_line(change, message):
    with pytest.raises(ConfigError, match=message):
        grid_from_lists(**{**BASE, **change})


@pytest.mark.parametrize('change', [{'truths': [['tracker_drift', 'timestamp_ofset']]},
                                    {'draws': truth_draws(1, [2], 1, ['tracker_drift', 'timestamp_ofset'])}])
def test_an_unknown_effect_in_a_truth_or_a_pool_names_the_closest(change):
    with pytest.raises(UnknownEffectError, match="unknown effect 'timestamp_ofset'; did you mean timestamp_offset"):
        grid_from_lists(**{**BASE, **change})


@pytest.mark.parametrize('text, message', [
    ('campaigns: [alignment]\nseeds: 1\ndraws: 3\n', 'draws must be a mapping with count, k, pool, seed'),
    ('campaigns: [alignment]\nseeds: 1\ndraws: {count: 3, kk: 2}\n', r'draws: unknown key\(s\) kk'),
    ('campaigns: [alignment]\nseeds: 1\ndraws: {k: 2}\n', 'draws: count missing'),
    ('campaigns: [alignment]\nseeds: 1\ndraws: {count: 3, pool: []}\n', 'draws: pool must be a non-empty list'),
    ('campaigns: [alignment]\nseeds: 1\ntruths: tracker_drift\n', 'truths must be a list'),
])
def test_bad_truths_in_a_grid_file_are_one_line(tmp_path, text, message):
    path = tmp_path / 'grid.yaml'
    path.write_text(text)
    with pytest.raises(ConfigError, match=f'grid.yaml: {message}'):
        grid_from_file(path)


@pytest.mark.parametrize('argv, message', [
    (['--truths', 'tracker_drift+timestamp_ofset'], "unknown effect 'timestamp_ofset'; did you mean timestamp_offset"),
    (['--draws', '2', '--draw-k', '2-x'], "--draw-k '2-x': give K, a range such as 2-3"),
    (['--draws', '2', '--draw-k', '12'], 'draws: k = 12 is outside 1..9'),
    (['--draw-seed', '3', '--controls', '1'], '--draw-seed shapes the draws: give --draws N too'),
    (['--controls', '1', '--search-rounds', '0'], '--search-rounds'),
    (['--grid', 'g.yaml', '--controls', '1'], '--grid and --controls both given'),
])
def test_bad_truth_flags_exit_2_with_one_line_and_write_nothing(tmp_path, capsys, argv, message):
    out = tmp_path / 'atlas'
    code = main(['atlas', '--out', str(out), *argv])
    lines = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(lines) == 1 and message in lines[0] and 'Traceback' not in lines[0]
    assert not out.exists()


# --- the scoring --------------------------------------------------------------------------------------------------

SWAP = [{'model': 'gyro_axis_swap instead of gyro_scale_factor (compared in full)', 'delta_bic': 1.9}]


@pytest.mark.parametrize('hidden, added, removed, status, competing, equivalents, absorbed, score', [
    (('a', 'b'), ('a', 'b'), (), 'explained', [], [], (), 'exact'),
    ((), (), (), 'explained', [], [], (), 'exact'),  # a control explained with nothing added
    ((), ('a',), (), 'explained', [], [], (), 'extra'),  # a control with a term added
    ((), (), (), 'missing_effect', [], [], (), 'missed'),  # a control left unexplained
    (('a', 'b'), ('a', 'b'), (), 'unexplained', [], [], (), 'missed'),
    (('a', 'b'), ('a', 'b'), ('gyro_bias',), 'explained', [], [], (), 'missed'),  # a true term taken out
    (('a', 'b'), ('a', 'c'), (), 'explained', [['c', 'b']], [], (), 'equivalent'),  # a stated competing set
    (('a', 'b'), ('a', 'c'), (), 'explained', [['c', 'd'], ['b']], [], (), 'missed'),  # c competes with d, not b
    (('gyro_axis_swap', 'x'), ('gyro_scale_factor', 'x'), (), 'explained', [], SWAP, (), 'equivalent'),
    (('a', 'b'), ('a',), (), 'explained', [], [], ('b',), 'equivalent'),  # absorbed: unobservable next to a
    (('a', 'b'), ('a',), (), 'explained', [], [], (), 'missed'),
    (('a', 'b'), ('a', 'b', 'c'), (), 'explained', [], [], (), 'extra'),
    (('a', 'b'), ('a', 'c', 'd'), (), 'explained', [['b', 'c']], [], (), 'extra'),  # b stood for, d extra
])
def test_the_score_of_a_final_model(hidden, added, removed, status, competing, equivalents, absorbed, score):
    assert score_truth(hidden, added, removed, status, stated_pairs(competing, equivalents), absorbed) == score


def test_the_competitors_a_comparison_states_are_its_competing_sets_and_the_rivals_of_its_terms():
    document = {'competing': [{'effects': ['hipo_fiducial_error', 'imager_boresight_offset']}],
                'model_terms': [{'term': 'gyro_scale_factor', 'rivals': [{'effect': 'gyro_axis_swap'}]},
                                {'term': 'gyro_bias', 'rivals': []}]}
    assert stated_competitors(document) == [['hipo_fiducial_error', 'imager_boresight_offset'],
                                            ['gyro_scale_factor', 'gyro_axis_swap']]
    assert confused_pairs(('a', 'b', 'c'), ('a', 'd')) == [('b', 'd'), ('c', 'd')]


def _truth_row(index, hidden, added, score, campaign='alignment', variant='reduced', competing=(), verdict='explained'):
    row = {name: None for name in ROW_FIELDS}
    row.update(key=f'{"+".join(hidden) or "none"}|1|{campaign}|{variant}|{index}|truth{index}',
               effect='+'.join(hidden) or 'none', size=1.0 if hidden else 0.0, campaign=campaign, variant=variant,
               seed=index, truth_effects=','.join(hidden), k=len(hidden), mode='search', rounds=3,
               final_added=','.join(added), final_removed='', verdict=verdict, competing=json.dumps(list(competing)),
               equivalents='[]', absorbed='', score=score)
    return row


ROWS = [
    _truth_row(0, ('a', 'b'), ('a', 'b'), 'exact'),
    _truth_row(1, ('a', 'c'), ('a', 'd'), 'equivalent', competing=[['c', 'd']]),
    _truth_row(2, ('b', 'c'), ('b', 'd'), 'missed', verdict='missing_effect'),
    _truth_row(3, ('a', 'b', 'c'), ('a', 'b', 'c'), 'exact'),
    _truth_row(4, (), (), 'exact'),
    _truth_row(5, (), ('e',), 'extra'),
    _truth_row(6, ('a', 'b'), ('a', 'b'), 'exact', campaign='star-hop'),
    {**_truth_row(7, ('a', 'b'), (), 'missed'), 'error': 'RuntimeError: boom'},  # failed: counts nowhere
]


def test_success_rates_per_campaign_and_k_with_the_controls():
    rates = {(rate.campaign, rate.k): rate for rate in truth_rates(ROWS)}
    assert set(rates) == {('alignment:reduced', 0), ('alignment:reduced', 2), ('alignment:reduced', 3),
                          ('star-hop:reduced', 2)}
    two = rates[('alignment:reduced', 2)]
    assert (two.successes, two.trials) == (2, 3) and two.counts == {'exact': 1, 'equivalent': 1, 'extra': 0,
                                                                    'missed': 1}
    assert two.low < 2 / 3 < two.high
    controls = rates[('alignment:reduced', 0)]
    assert (controls.successes, controls.trials, controls.counts['extra']) == (1, 2, 1)


def test_the_pairs_most_often_confused_and_whether_they_were_stated():
    confused = {(c.hidden, c.named, c.campaign): (c.count, c.stated) for c in truth_confusions(ROWS)}
    assert confused == {('c', 'd', 'alignment:reduced'): (2, 1)}  # row 1 stated c or d, row 2 did not
    assert [row['key'] for row in truth_misses(ROWS)] == [ROWS[2]['key'], ROWS[5]['key']]


def test_table_6_5_takes_the_truth_controls_and_never_a_truth_with_effects():
    misaligned = dict(measurements=4, misalignment_el_arcsec=1.0, misalignment_xel_arcsec=1.0,
                      predicted_sigma_el_arcsec=1.0, predicted_sigma_los_arcsec=1.0)
    rows = [{**ROWS[4], **misaligned, 'misalignment_los_arcsec': 10.0},
            {**ROWS[0], **misaligned, 'misalignment_los_arcsec': 1000.0}]
    table, which = table_6_5_slice(rows)
    assert which == 'control runs (size 0)' and table[0].runs == 1 and table[0].los_rms_arcsec == 10.0
    assert table_6_5_slice(rows[1:])[0] == []


def test_the_report_has_the_truth_tables(tmp_path):
    summary = summarize(ROWS)
    text = text_table(summary)
    assert 'truths: right = exact, or equivalent' in text and max(map(len, text.splitlines())) <= 120
    assert 'alignment:reduced     2        2/3' in text and 'c -> d (alignment:reduced): 2x, 1 stated' in text
    assert 'missed: b+c|1|alignment|reduced|2|truth2: hidden b,c -> final +b +d (missing_effect, 3 comparisons)' in text
    page = write_html(summary, tmp_path / 'report', 'truths').read_text()
    assert 'Truths with several effects: success per campaign and k' in page and '0 (controls)' in page
    assert summary.points == [] and summary.calibration == []  # truth rows are no single-effect cells
    assert 'Detection probability' not in page


# --- one tiny grid end to end -------------------------------------------------------------------------------------

@pytest.mark.timeout(600)
def test_a_control_and_a_two_effect_truth_searched_on_the_local_cluster(tmp_path, capsys):
    out = tmp_path / 'atlas'
    code = main(['atlas', '--out', str(out), '--campaigns', 'alignment:minimal', '--seeds', '1', '--workers', '2',
                 '--truths', 'imager_rotation_of_field+timestamp_offset', '--controls', '1', '--search-rounds', '2',
                 '--candidates', 'imager_rotation_of_field,timestamp_offset,imager_boresight_offset'])
    captured = capsys.readouterr()
    assert code == 0, captured.err
    assert 'atlas: 2 tasks (2 truths over 1 campaigns (the search, up to 2 rounds) x 1 seeds)' in captured.out
    rows = {row['k']: row for row in pq.read_table(out / 'table').to_pylist()}
    assert set(rows) == {0, 2} and all(row['error'] is None for row in rows.values())
    control, truth = rows[0], rows[2]
    assert control['truth_effects'] == '' and control['effect'] == 'none' and control['size'] == 0.0
    assert truth['truth_effects'] == 'imager_rotation_of_field,timestamp_offset' and truth['seed'] == 1
    for row in rows.values():
        assert row['mode'] == 'search' and 1 <= row['rounds'] <= 2 and row['score'] in SCORES
        assert row['verdict'] in ('explained', 'missing_effect', 'unexplained')
        stated = stated_pairs(json.loads(row['competing']), [{'model': m} for m in json.loads(row['equivalents'])])
        assert row['score'] == score_truth(row['truth_effects'].split(',') if row['k'] else (),
                                           filter(None, row['final_added'].split(',')),
                                           filter(None, row['final_removed'].split(',')), row['verdict'], stated,
                                           filter(None, row['absorbed'].split(',')))
    assert 'truths: right = exact' in captured.out and (out / 'report' / 'index.html').exists()


def test_the_truths_of_several_campaigns_take_turns_so_that_a_partial_atlas_has_both():
    grid = grid_from_lists(**{**BASE, 'campaigns': ['alignment:reduced', 'star-hop:reduced']},
                           draws=truth_draws(3, [2], 7), controls=1, search_rounds=3)
    order = [(task.campaign, task.truth_index) for task in grid.tasks()]
    assert order == [(campaign, number) for number in range(4) for campaign in ('alignment', 'star-hop')]
