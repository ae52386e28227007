"""The JSON Schemas of docs/schemas/ against real `--json` outputs (issue 26: a typed contract).

Real documents: `sofia compare` of the session's reduced alignment bag (with `--search`, which adds
only the `search` key), of every measurement set in data/thesis-2004/, and `sofia noise` of a short
TC-3 gyro-stability bag; then documents broken one way each, which the schemas must refuse.
"""

import contextlib
import copy
import io
from pathlib import Path

import pytest


from json_contract import ContractViolation, load_json, validate_compare, validate_noise  # noqa: E402

from sofia_ros.cli import main  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
NOMINAL_MODEL = ROOT / 'config' / 'model' / 'nominal.yaml'
SETS = sorted((ROOT / 'data' / 'thesis-2004').glob('*.yaml'))
#: The noise test's model (test_noise_cli.py): a line the bag does not have, misalignment for Table 5.7.
NOISE_MODEL = ('effects:\n  gyro_noise: {}\n  gyro_misalignment: {}\n'
               '  vibration_lines: {frequencies_hz: [0.7], amplitudes_arcsec_per_s: [0.05], axes: [el]}\n')
#: 10.8 s of TC-3: 4320 samples, 2160 after --decimate 2 (the analysis needs 1024); lines and candidates show.
NOISE_HOURS = 0.003


def _written(arguments, out):
    """Run `sofia ARGUMENTS --json OUT` quietly; the document it wrote, parsed strictly."""
    with contextlib.redirect_stdout(io.StringIO()):
        assert main([*arguments, '--json', str(out)]) == 0
    return load_json(out)


@pytest.fixture(scope='module')
def set_documents(tmp_path_factory):
    folder = tmp_path_factory.mktemp('set_json')
    return {path.stem: _written(['compare', str(path), '--model', str(NOMINAL_MODEL)], folder / f'{path.stem}.json')
            for path in SETS}


@pytest.fixture(scope='module')
def noise_document(campaign_bags, tmp_path_factory):
    from sofia_ros.campaigns.gyro_stability import run_gyro_stability
    from sofia_ros.config import parse_effect_config

    truth = parse_effect_config('effects:\n  gyro_noise: {}\n  gyro_misalignment: {}\n  gyro_bias: {}\n')
    bag = campaign_bags.get(f'gyro-stability-TC-3-{NOISE_HOURS}h-seed8', lambda path: run_gyro_stability(
        truth, case='TC-3', hours=NOISE_HOURS, seed=8, bag_path=path))
    folder = tmp_path_factory.mktemp('noise_json')
    model = folder / 'noise.yaml'
    model.write_text(NOISE_MODEL)
    return _written(['noise', str(bag), '--model', str(model), '--decimate', '2'], folder / 'noise.json')


def test_the_compare_of_a_bag_with_search_keeps_the_contract(campaign_bags, tmp_path):
    document = _written(['compare', str(campaign_bags.reduced_alignment()), '--model', str(NOMINAL_MODEL),
                         '--search', '--search-rounds', '1'], tmp_path / 'compare.json')
    validate_compare(document)
    validate_compare({key: value for key, value in document.items() if key != 'search'})  # without --search
    assert document['search']['rounds'][0]['round'] == 1


def test_the_compare_of_every_thesis_measurement_set_keeps_the_contract(set_documents):
    assert len(set_documents) == len(SETS) >= 7
    for name, document in set_documents.items():
        try:
            validate_compare(document)
        except ContractViolation as violation:
            raise AssertionError(f'{name}: {violation}') from None


def test_the_noise_analysis_keeps_the_contract(noise_document):
    validate_noise(noise_document)
    # What the schema's optional branches are there for is in this document.
    assert 'arw_sampled_arcsec_per_sqrt_s' in noise_document['axes']['el']
    assert noise_document['earth_rate_deg_per_h']['misalignment_corrected'] is not None
    assert noise_document['candidates']


def _set(path, value):
    """A mutation that puts ``value`` at ``path`` (keys and indices)."""
    def mutate(document):
        *parents, last = path
        for key in parents:
            document = document[key]
        document[last] = value
    return mutate


def _delete(path):
    def mutate(document):
        *parents, last = path
        for key in parents:
            document = document[key]
        del document[last]
    return mutate


def _first_sigma_to(value):
    def mutate(document):
        sigma = next(c['sigma'] for c in document['candidates'] if c['sigma'])
        sigma[next(iter(sigma))] = value
    return mutate


COMPARE_BREAKS = {
    'verdict status outside the enum': (_set(('verdict', 'status'), 'missing effect'),
                                        "'missing effect' is not one of"),
    'next action outside the enum': (_set(('verdict', 'next', 'action'), 'fix'), "'fix' is not one of"),
    'an add without its command': (_set(('verdict', 'next'), {'action': 'add', 'effect': 'gyro_bias', 'term': None,
                                                              'command': None}), "None is not of type 'string'"),
    'a remove without its term': (_set(('verdict', 'next'), {'action': 'remove', 'effect': None, 'term': None,
                                                             'command': 'sofia model remove'}),
                                  "None is not of type 'string'"),
    'a headline over 100 characters': (_set(('verdict', 'headline'), 'x' * 101), 'is too long'),
    'a headline that ends without a command': (_set(('verdict', 'headline'), 'missing_effect: add it'), 'does not match'),
    'a headline of another status': (_set(('verdict', 'headline'), 'explained: nothing to do'),
                                     "does not match '\\^missing_effect: '"),
    'verdict.next missing': (_delete(('verdict', 'next')), "'next' is a required property"),
    'candidates missing': (_delete(('candidates',)), "'candidates' is a required property"),
    'a sigma written as the string NaN': (_first_sigma_to('NaN'), "'NaN' is not of type 'number', 'null'"),
    'an RMS written as the string inf': (_set(('residual_rms_arcsec', 'total'), 'inf'), "'inf' is not of type"),
    'a NaN float': (_set(('noise_floor_arcsec',), float('nan')), 'nan is not a finite number'),
    'an undocumented key': (_set(('verdict_v2',),  {}), 'Additional properties are not allowed'),
}

NOISE_BREAKS = {
    'earth_rate_deg_per_h missing': (_delete(('earth_rate_deg_per_h',)), "'earth_rate_deg_per_h' is a required"),
    'a sigma written as the string Infinity': (_set(('axes', 'el', 'arw_sigma'), 'Infinity'), "'Infinity' is not of"),
    'an unknown case': (_set(('case',), 'TC-5'), "'TC-5' is not one of"),
    'a candidate of no documented effect': (_set(('candidates', 0, 'effect'), 'gyro_bias'), "'gyro_bias' is not one"),
    'degenerate without the 5.2.4 pair first': (_set(('degenerate',), []), 'should be non-empty'),
}


@pytest.mark.parametrize('name', sorted(COMPARE_BREAKS))
def test_a_broken_compare_document_is_refused(set_documents, name):
    mutate, message = COMPARE_BREAKS[name]
    document = copy.deepcopy(set_documents['star-hop-2004-09-03'])
    validate_compare(document)
    mutate(document)
    with pytest.raises(ContractViolation, match=message):
        validate_compare(document)


@pytest.mark.parametrize('name', sorted(NOISE_BREAKS))
def test_a_broken_noise_document_is_refused(noise_document, name):
    mutate, message = NOISE_BREAKS[name]
    document = copy.deepcopy(noise_document)
    mutate(document)
    with pytest.raises(ContractViolation, match=message):
        validate_noise(document)


def test_a_file_with_a_nan_token_is_not_json(tmp_path):
    path = tmp_path / 'nan.json'
    path.write_text('{"noise_floor_arcsec": NaN}\n')
    with pytest.raises(ContractViolation, match='NaN is not JSON'):
        load_json(path)


def test_the_schemas_bag_variables_are_every_variable_the_structure_tests_name():
    # The gyro axes' `rate` and `rate_size` were named in trends of real bags and missing from the schema.
    import json

    from sofia_ros.compare.diagnostics import FRAME_VARIABLES, GYRO_TEST_VARIABLES, NAMING_PREFERENCE, ROW_VARIABLES
    from sofia_ros.effects.empirical import DETECTOR_FIELD

    schema = json.loads((ROOT / 'docs' / 'schemas' / 'compare.schema.json').read_text())
    named = {*FRAME_VARIABLES, *ROW_VARIABLES, *GYRO_TEST_VARIABLES, DETECTOR_FIELD}
    assert set(schema['$defs']['bag_variable']['enum']) == named == set(NAMING_PREFERENCE)
