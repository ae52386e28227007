"""Measurement sets refused in one line: file limits, physical ranges, YAML slips, and generated bad values.

Each refusal here was a wrong result at exit 0, a traceback or a hang before the loader had limits
(docs/measurement-sets.md, Limits). A refused set never reaches the fit, so these run in milliseconds.
"""

import copy
import math
from pathlib import Path

import pytest
import yaml

from sofia_ros.cli import main
from sofia_ros.config import MAX_YAML_NODES
from sofia_ros.errors import ConfigError
from sofia_ros.measurements.format import MAX_SET_BYTES, MAX_SET_ROWS
from sofia_ros.measurements import validate
from sofia_ros.measurements.validate import load_measurement_set, parse_measurement_set

REPO = Path(__file__).resolve().parents[1]
DATA = REPO / 'data' / 'thesis-2004'
NOMINAL = REPO / 'config' / 'model' / 'nominal.yaml'
EARTH_RATE = DATA / 'edwards-earth-rate-2007.yaml'
ALIGNMENT = DATA / 'alignment-2004.yaml'
STAR_HOP = DATA / 'star-hop-2004-09-03.yaml'
#: Table D.2's A5 with its first row negated: A A^T = I still, but a mirror image (determinant -1).
MIRRORED_A5 = [[-0.9998608004680677, -0.0162982292, 0.003570264345],
               [-0.0162798975, 0.99985444234, 0.00510480865],
               [0.003652944007, -0.00503695892673, 0.99998110890042]]
SWAP_EL_XEL = [[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]]


def _document(path):
    return yaml.safe_load(path.read_text())


def _text(document):
    return yaml.safe_dump(document, sort_keys=False)


def _set_in(tmp_path, text):
    path = tmp_path / 'set.yaml'
    path.write_bytes(text if isinstance(text, bytes) else text.encode())
    return path


def _refused_by_the_cli(capsys, path, out, model=NOMINAL):
    """`sofia compare` on the set: exit 2, one `sofia: error:` line, no traceback, no --json left; the line."""
    code = main(['compare', str(path), '--model', str(model), '--json', str(out)])
    captured = capsys.readouterr()
    lines = captured.err.splitlines()
    assert code == 2, captured.err
    assert len(lines) == 1 and lines[0].startswith('sofia: error:'), captured.err
    assert 'Traceback' not in captured.err and captured.out == ''
    assert not out.exists()
    return lines[0]


# --- the shipped sets fit the limits --------------------------------------------------------------------------

def _shipped_sets():
    return sorted(path for folder in ('data', 'config') for path in (REPO / folder).rglob('*.y*ml')
                  if any(line.startswith('measurement_set:') for line in path.read_text().splitlines()))


def test_every_shipped_set_loads_within_the_caps():
    """Every measurement set under data/ and config/ loads through the capped reader and safe_load_limited."""
    paths = _shipped_sets()
    assert len(paths) >= 7
    for path in paths:
        measurement_set = load_measurement_set(path)
        assert path.stat().st_size < MAX_SET_BYTES / 100
        assert sum(len(table.rows) for table in measurement_set.tables) < MAX_SET_ROWS / 50
    # The row cap itself fits the YAML node cap: a row of the widest kind (15 columns) is 16 nodes.
    assert MAX_SET_ROWS * 16 < MAX_YAML_NODES / 2


# --- item 1: limits on the file -------------------------------------------------------------------------------

def test_a_link_to_dev_zero_is_refused_before_reading(tmp_path, capsys):
    link = tmp_path / 'zero.yaml'
    link.symlink_to('/dev/zero')
    assert 'is not a regular file' in _refused_by_the_cli(capsys, link, tmp_path / 'out.json')


def test_a_file_over_the_byte_cap_is_refused_naming_the_cap(tmp_path):
    path = _set_in(tmp_path, '#' * MAX_SET_BYTES + '\n')
    with pytest.raises(ConfigError, match=rf'larger than {MAX_SET_BYTES} bytes, the most a measurement set may'):
        load_measurement_set(path)


def test_more_rows_than_the_cap_are_refused_before_a_row_is_read(monkeypatch):
    """A cap of 4 against Table 5.7's five rows, the last of them unreadable: the count is checked first."""
    monkeypatch.setattr(validate, 'MAX_SET_ROWS', 4)
    text = EARTH_RATE.read_text().replace('10.5024, -10.5465', 'not, numbers')
    with pytest.raises(ConfigError, match=rf'set.yaml: 5 rows, more than the 4 a measurement set may have \(at most '
                                          rf'{MAX_SET_BYTES} bytes\); split it into sets'):
        parse_measurement_set(text, 'set.yaml')


# --- item 2: wrong results at exit 0 ---------------------------------------------------------------------------

def test_a_mirror_image_matrix_is_refused():
    document = _document(EARTH_RATE)
    document['matrices']['A5'] = MIRRORED_A5
    with pytest.raises(ConfigError, match=r'matrices.A5 is a reflection \(determinant -1\), not a rotation'):
        parse_measurement_set(_text(document), 'set.yaml')


def test_the_identity_none_cannot_be_redefined():
    document = _document(ALIGNMENT)
    document['matrices']['none'] = SWAP_EL_XEL
    with pytest.raises(ConfigError, match=r"matrices.none: 'none' is always the identity"):
        parse_measurement_set(_text(document), 'set.yaml')


@pytest.mark.parametrize('path, key, value, message', [
    (EARTH_RATE, ('tables', 0, 'latitude_deg'), 200, r'latitude_deg must be between -90 and 90 deg \(a latitude\), '
                                                      r'got 200'),
    (STAR_HOP, ('heading_deg',), 1e308, r'heading_deg must be between -360 and 360 deg .* got 1e\+308'),
    (EARTH_RATE, ('gyro_temperature_c',), -300, r'gyro_temperature_c must be between -90 and 100 C .* got -300'),
])
def test_values_outside_their_physical_range_are_refused(path, key, value, message):
    document = _document(path)
    target = document
    for step in key[:-1]:
        target = target[step]
    target[key[-1]] = value
    with pytest.raises(ConfigError, match=message):
        parse_measurement_set(_text(document), 'set.yaml')


@pytest.mark.parametrize('version', [True, 1.0])
def test_the_format_version_must_be_the_integer_1(version):
    """`measurement_set: true` was version 1 (True == 1 in Python); a bool is no number anywhere in a set."""
    document = _document(EARTH_RATE)
    document['measurement_set'] = version
    with pytest.raises(ConfigError, match=rf'not a measurement set \(needs measurement_set: 1 at the top, got '
                                          rf'{version!r}\)'):
        parse_measurement_set(_text(document), 'set.yaml')


def test_a_bool_in_a_matrix_is_refused():
    document = _document(EARTH_RATE)
    document['matrices']['A5'] = [[True, False, False], [False, True, False], [False, False, True]]
    with pytest.raises(ConfigError, match=r'matrices.A5 must be a finite number, got True'):
        parse_measurement_set(_text(document), 'set.yaml')


def test_a_key_given_twice_is_refused():
    text = EARTH_RATE.read_text().replace('gyro_temperature_c: 22.8\n', 'gyro_temperature_c: 22.8\n'
                                                                        'gyro_temperature_c: 50.0\n')
    with pytest.raises(ConfigError, match=r"set.yaml: key 'gyro_temperature_c' given twice \(line \d+\); keep one"):
        parse_measurement_set(text, 'set.yaml')


def test_a_column_given_twice_is_refused():
    """zip() into a row would have kept the second sigma without a word."""
    document = _document(EARTH_RATE)
    table = document['tables'][0]
    table['columns'][5] = 'sigma_deg_per_h'
    with pytest.raises(ConfigError, match=r"column 'sigma_deg_per_h' given twice; keep one"):
        parse_measurement_set(_text(document), 'set.yaml')


@pytest.mark.parametrize('maneuvers, message', [(-6, r'maneuvers must be between 1 and 1e\+04 maneuvers'),
                                                (6.5, r'maneuvers must be a whole number, got 6.5')])
def test_the_number_of_maneuvers_is_a_positive_whole_number(maneuvers, message):
    document = _document(ALIGNMENT)
    document['tables'][0]['rows'][0][6] = maneuvers
    with pytest.raises(ConfigError, match=rf"table 'turning_points' row 1 {message}"):
        parse_measurement_set(_text(document), 'set.yaml')


@pytest.mark.parametrize('star', ['HIP -5', 'HIP 5.0', 'hip-11767'])
def test_a_hip_designation_is_hip_and_a_positive_number(star):
    """The catalogue's name key drops the sign and the point: "HIP -5" was HIP 5, "HIP 5.0" HIP 50."""
    document = _document(STAR_HOP)
    document['tables'][0]['rows'][0][1] = star
    with pytest.raises(ConfigError, match=rf"row 1: '{star}' is not a Hipparcos number; write \"HIP\" and a "
                                          r'positive whole number'):
        parse_measurement_set(_text(document), 'set.yaml')


@pytest.mark.parametrize('sigma', [1e-300, 0.0, 1e308])
def test_a_sigma_outside_1e_6_to_1e4_arcsec_is_refused(sigma):
    """1e-300 overflowed the fit's weights into a meaningless ranking; 1e308 ended in a TypeError."""
    document = _document(STAR_HOP)
    document['tables'][0]['rows'][0][6] = sigma
    with pytest.raises(ConfigError, match=r'row 1 sigma_arcsec must be between 1e-06 and 1e\+04 arcsec \(below '
                                          r'1e-06" the fit\'s weights overflow, above 1e\+04" a row weighs nothing\)'):
        parse_measurement_set(_text(document), 'set.yaml')


def test_a_number_yaml_reads_as_text_gets_the_hint():
    """YAML 1.1 reads 1e-6 (no point) as text: the message says how to write it."""
    text = EARTH_RATE.read_text().replace('0.2601, 0.015,', '0.2601, 1e-2,')
    with pytest.raises(ConfigError, match=r"sigma_deg_per_h must be a finite number, got '1e-2' \(text: .* write "
                                          r'1.0e-6, unquoted\)'):
        parse_measurement_set(text, 'set.yaml')


# --- item 3: tracebacks ----------------------------------------------------------------------------------------

def test_bytes_that_are_not_utf8_are_one_line(tmp_path, capsys):
    path = _set_in(tmp_path, EARTH_RATE.read_bytes().replace(b'Edwards', b'Edw\xffards'))
    assert 'not UTF-8 text (byte' in _refused_by_the_cli(capsys, path, tmp_path / 'out.json')


def test_a_sigma_of_1e308_is_one_line(tmp_path, capsys):
    document = _document(EARTH_RATE)
    document['tables'][0]['rows'][2][4] = 1e308
    line = _refused_by_the_cli(capsys, _set_in(tmp_path, _text(document)), tmp_path / 'out.json')
    assert "row 3 sigma_deg_per_h must be between 1e-06 and 1e+04 deg/h" in line


# --- generated: each field of three small sets x each kind of bad value, through the CLI --------------------------

NUMBER_BAD = {'true': True, 'text-exponent': '1e-6', 'list': [1.0], 'nan': math.nan, 'inf': math.inf,
              'huge': 1e308, 'minus-huge': -1e308, 'huge-integer': 10 ** 400}
COUNT_BAD = {**NUMBER_BAD, 'negative': -6, 'fraction': 6.5, 'zero': 0}
TIME_BAD = {'not-a-time': 'soon', 'no-offset': '2004-09-03T04:22:16', 'impossible': '2004-13-45T99:00:00Z',
            'year-1': '0001-01-01T00:00:00+05:00', 'year-9999': '9999-12-31T23:59:59-05:00', 'true': True,
            'integer': 5, 'list': [1]}
STAR_BAD = {'unknown': 'Alpha Nowhere', 'hip-negative': 'HIP -5', 'hip-fraction': 'HIP 5.0', 'hip-zero': 'HIP 0',
            'integer': 5, 'true': True, 'null': None, 'list': [1]}
MATRIX_BAD = {'mirror': MIRRORED_A5, 'two-by-two': [[1.0, 0.0], [0.0, 1.0]], 'bools': [[True] * 3] * 3,
              'texts': [['1', '0', '0'], ['0', '1', '0'], ['0', '0', '1']], 'twice-identity': [[2.0, 0, 0], [0, 2.0, 0],
                                                                                               [0, 0, 2.0]],
              'text': 'abc', 'rows-of-text': ['abc', 'def', 'ghi']}
MATRIX_NAME_BAD = {'unknown': 'A9', 'true': True, 'null': None, 'list': [1]}
VERSION_BAD = {'true': True, 'float': 1.0, 'two': 2, 'text': '1', 'null': None}
KIND_BAD = {'unknown': 'nope', 'true': True, 'list': [1], 'null': None, 'mapping': {'a': 1}}
TABLES_BAD = {'empty': [], 'text': 'abc', 'null': None, 'mapping': {'a': 1}, 'list-of-number': [5]}
ROWS_BAD = {'empty': [], 'text': 'abc', 'short-row': [[1, 2]], 'null': None, 'null-row': [None]}
COLUMNS_BAD = {'text': 'abc', 'empty': [], 'numbers': [1, 2], 'null': None}
AXIS_BAD = {'unknown': 'w', 'true': True, 'integer': 5, 'null': None}
FRAME_BAD = {'unknown': 'body', 'true': True, 'list': [1]}
FRAME_MATRIX_BAD = {'unknown': 'A9', 'list': [1], 'null': None, 'true': True, 'mapping': {'a': 1}}
FLAG_BAD = {'text': 'yes', 'integer': 1, 'null': None}
MATRIX_DEFINITION_BAD = {'none-swapped': ('none', SWAP_EL_XEL), 'none-identity': ('none', [[1.0, 0, 0], [0, 1.0, 0],
                                                                                         [0, 0, 1.0]]),
                         'name-with-space': ('A 5', SWAP_EL_XEL), 'name-bool': (True, SWAP_EL_XEL)}

#: (set, path to the field, its bad values); a set is refused for each value at that place.
FIELDS = [
    ('rate', ('site', 'latitude_deg'), NUMBER_BAD),
    ('rate', ('gyro_temperature_c',), NUMBER_BAD),
    ('rate', ('matrices', 'A5', 0, 0), NUMBER_BAD),
    ('rate', ('tables', 0, 'latitude_deg'), NUMBER_BAD),
    ('rate', ('tables', 0, 'heading_deg'), NUMBER_BAD),
    ('rate', ('tables', 0, 'elevation_deg'), NUMBER_BAD),
    ('rate', ('tables', 0, 'rows', 0, 1), NUMBER_BAD),
    ('rate', ('tables', 0, 'rows', 0, 4), NUMBER_BAD),
    ('align', ('tables', 0, 'rows', 0, 1), NUMBER_BAD),
    ('align', ('tables', 0, 'rows', 0, 3), NUMBER_BAD),
    ('align', ('tables', 0, 'rows', 0, 4), NUMBER_BAD),
    ('align', ('tables', 2, 'rows', 0, 2), NUMBER_BAD),
    ('align', ('tables', 2, 'rows', 0, 3), NUMBER_BAD),
    ('hop', ('heading_deg',), NUMBER_BAD),
    ('hop', ('tables', 0, 'rows', 0, 5), NUMBER_BAD),
    ('hop', ('tables', 0, 'rows', 0, 6), NUMBER_BAD),
    ('align', ('tables', 0, 'rows', 0, 6), COUNT_BAD),
    ('rate', ('epoch_utc',), TIME_BAD),
    ('hop', ('tables', 0, 'rows', 0, 2), TIME_BAD),
    ('hop', ('tables', 0, 'rows', 0, 1), STAR_BAD),
    ('rate', ('matrices', 'A5'), MATRIX_BAD),
    ('align', ('matrices',), {f'{kind}': {name: value} for kind, (name, value) in MATRIX_DEFINITION_BAD.items()}),
    ('align', ('tables', 0, 'rows', 0, 0), MATRIX_NAME_BAD),
    ('rate', ('measurement_set',), VERSION_BAD),
    ('rate', ('tables', 0, 'kind'), KIND_BAD),
    ('hop', ('tables',), TABLES_BAD),
    ('rate', ('tables', 0, 'rows'), ROWS_BAD),
    ('hop', ('tables', 0, 'columns'), COLUMNS_BAD),
    ('align', ('tables', 2, 'rows', 0, 1), AXIS_BAD),
    ('rate', ('tables', 0, 'gyro_frame'), FRAME_BAD),
    ('rate', ('tables', 0, 'tarf_from_gyrf'), FRAME_MATRIX_BAD),
    ('hop', ('tables', 0, 'drift_removed'), FLAG_BAD),
]


def _small(path, rows=2):
    """A shipped set cut to its first rows, without its free text (a short file to parse, case after case)."""
    document = {key: value for key, value in _document(path).items() if key not in ('title', 'source')}
    for table in document['tables']:
        table.pop('provenance', None)
        keep = [index for index, column in enumerate(table['columns']) if column != 'source']
        table['columns'] = [table['columns'][index] for index in keep]
        table['rows'] = [[row[index] for index in keep] for row in table['rows'][:rows]]
    return document


def _base_documents():
    """Three small valid sets: Table 5.7's means, the 2004 alignment, the first two moves of the star hop."""
    return {'rate': _small(EARTH_RATE), 'align': _small(ALIGNMENT), 'hop': _small(STAR_HOP)}


BASES = _base_documents()


def _mutated(base, path, value):
    document = copy.deepcopy(BASES[base])
    target = document
    for step in path[:-1]:
        target = target[step]
    if path == ('matrices',):
        target['matrices'] = {**target['matrices'], **value}
    else:
        target[path[-1]] = value
    return _text(document)


def _cases():
    for base, path, values in FIELDS:
        for kind, value in values.items():
            yield pytest.param(base, path, value, id=f'{base}-{".".join(map(str, path))}-{kind}')


CASES = list(_cases())


def test_the_generator_covers_enough_cases_and_the_bases_are_valid():
    assert len(CASES) >= 80
    for base, document in BASES.items():
        parse_measurement_set(_text(document), base)


@pytest.fixture(scope='module')
def short_model(tmp_path_factory):
    """A one-effect model: the set is refused before the model matters, and it is read case after case."""
    path = tmp_path_factory.mktemp('model') / 'model.yaml'
    path.write_text('effects: {earth_rotation: {}}\n')
    return path


@pytest.mark.filterwarnings('error')  # a RuntimeWarning (overflow) would be a second line on stderr
@pytest.mark.parametrize('base, path, value', CASES)
def test_a_generated_bad_value_is_one_line_and_exit_2(tmp_path, capsys, short_model, base, path, value):
    path_of_set = _set_in(tmp_path, _mutated(base, path, value))
    _refused_by_the_cli(capsys, path_of_set, tmp_path / 'out.json', short_model)


@pytest.mark.parametrize('name', ['../../keep', 'a/b', '.hidden', 5, ''])
def test_a_table_name_that_is_no_file_name_is_refused(tmp_path, capsys, name):
    # The report names each table's plot after it: '../../keep' overwrote keep.png outside the report, at exit 0.
    document = _document(STAR_HOP)
    document['tables'][0]['name'] = name
    assert 'is not a table name' in _refused_by_the_cli(capsys, _set_in(tmp_path, _text(document)), tmp_path / 'o.json')


def test_a_distance_from_a_star_to_itself_is_refused(tmp_path, capsys):
    document = _document(STAR_HOP)
    row = document['tables'][0]['rows'][0]
    row[3] = row[1]
    line = _refused_by_the_cli(capsys, _set_in(tmp_path, _text(document)), tmp_path / 'o.json')
    assert 'star_1 and star_2 are the same star' in line


def test_half_of_a_column_group_is_refused_not_dropped(tmp_path, capsys):
    # el_arcsec without xel_arcsec was dropped without a word.
    document = _document(STAR_HOP)
    table = document['tables'][0]
    table['columns'].insert(6, 'el_arcsec')
    for row in table['rows']:
        row.insert(6, 5.0)
    line = _refused_by_the_cli(capsys, _set_in(tmp_path, _text(document)), tmp_path / 'o.json')
    assert 'xel_arcsec missing beside el_arcsec' in line
