"""Parse and validate a measurement-set YAML file: one-line ConfigErrors naming the table, row and fix."""

from __future__ import annotations

import datetime as dt
import math
import re
from os import PathLike

import numpy as np

from sofia_ros.config import safe_load_limited
from sofia_ros.errors import ConfigError, InvalidArgumentError, SofiaError
from sofia_ros.frames import AXES
from sofia_ros.input_files import read_text_capped
from sofia_ros.measurements.format import (
    FORMAT_VERSION,
    IDENTITY_MATRIX,
    KINDS,
    MAX_SET_BYTES,
    MAX_SET_ROWS,
    VALUE_RANGES,
    EarthRateMean,
    MeasurementSet,
    MisalignmentAngle,
    StarDistance,
    Table,
    TurningPoint,
)
from sofia_ros.sky.catalogue import find_star
from sofia_ros.sky.distances import spherical_sum_arcsec
from sofia_ros.sky.places import Site, Weather

__all__ = ['load_measurement_set', 'parse_measurement_set', 'is_measurement_set_path']

_TOP_KEYS = {'measurement_set', 'title', 'source', 'site', 'epoch_utc', 'night_utc', 'weather', 'heading_deg',
             'gyro_temperature_c', 'matrices', 'tables'}
_TABLE_KEYS = {'name', 'kind', 'provenance', 'columns', 'rows'}
#: Eq. 4.38 of a move's printed Euler angles against its printed distance (Table D.6 agrees to 0.1").
_EULER_TOLERANCE_ARCSEC = 0.5
_UNIT_SUFFIXES = ('_arcsec', '_arcmin', '_deg', '_rad', '_px', '_deg_per_h', '_rad_per_s', '_arcsec_per_s', '_mas',
                  '_utc', '_cdt', '_s', '_h', '_min')
#: Star times and the epoch: ERFA's places and the Hipparcos proper motions hold for these years.
_YEARS = (1900, 2199)
#: A matrix name is printed in messages and the report: one short word.
_MATRIX_NAME = re.compile(r'[A-Za-z0-9_.+-]{1,40}')
#: The catalogue's name key drops spaces and signs, so "HIP -5" or "HIP 5.0" would find HIP 5 or HIP 50:
#: a HIP designation must be exactly "HIP" and a positive whole number.
_HIP_PREFIX = re.compile(r'\s*hip(?![a-z])', re.IGNORECASE)
_HIP_DESIGNATION = re.compile(r'\s*hip\s*0*[1-9][0-9]*\s*', re.IGNORECASE)


def is_measurement_set_path(path: str | PathLike[str]) -> bool:
    """True for a file path ending .yaml or .yml (a bag is a directory).

    Args:
        path: the path given on the command line.

    Returns:
        Whether it names a measurement set rather than a bag (by its suffix alone).
    """
    return str(path).lower().endswith(('.yaml', '.yml'))


def load_measurement_set(path: str | PathLike[str]) -> MeasurementSet:
    """Read and validate a measurement set of at most MAX_SET_BYTES; ConfigError (one line) on any problem.

    Args:
        path: a measurement-set YAML file.

    Returns:
        The parsed set.

    Raises:
        ConfigError: the file is no regular file, too large, not UTF-8, or not a valid set.
    """
    text = read_text_capped(path, MAX_SET_BYTES, 'measurement set')
    return parse_measurement_set(text, str(path))


def _shown(value):
    """A value as a message shows it: its repr, one line, at most 40 characters."""
    text = repr(value)
    return text if len(text) <= 40 else text[:37] + '...'


def _listed(names, most=5):
    """Up to ``most`` names for a message, the rest counted."""
    shown = sorted(_shown(name) for name in names)
    rest = f' and {len(shown) - most} more' if len(shown) > most else ''
    return ', '.join(shown[:most]) + rest


def _first_repeated(names):
    seen = set()
    for name in names:
        if name in seen:
            return name
        seen.add(name)
    return None


def _mapping(value, where, source):
    if not isinstance(value, dict):
        raise ConfigError(f'{source}: {where} must be a mapping')
    return value


def _number(value, where, source):
    # bool is an int in Python: `true` where a number belongs is a slip, not 1.
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        hint = ''
        if isinstance(value, str) and _reads_as_number(value):
            hint = ' (text: YAML reads 1e-6 or a quoted number as text; write 1.0e-6, unquoted)'
        raise ConfigError(f'{source}: {where} must be a finite number, got {_shown(value)}{hint}')
    try:
        number = float(value)
    except OverflowError as err:
        raise ConfigError(f'{source}: {where} must be a finite number, got an integer of {len(str(value))} '
                          'digits') from err
    if not math.isfinite(number):
        raise ConfigError(f'{source}: {where} must be a finite number, got {value!r}')
    return number


def _reads_as_number(text):
    try:
        float(text)
    except ValueError:
        return False
    return True


def _ranged(value, key, where, source):
    """A number within VALUE_RANGES[key]; ConfigError naming the range, its unit and why otherwise."""
    low, high, unit, why = VALUE_RANGES[key]
    number = _number(value, where, source)
    if not low <= number <= high:
        raise ConfigError(f'{source}: {where} must be between {low:.3g} and {high:.3g} {unit} ({why}), '
                          f'got {number:.6g}; check the units and the value')
    return number


def _count(value, key, where, source):
    """A whole number (not a bool, not 6.5) within VALUE_RANGES[key]."""
    if isinstance(value, bool) or not isinstance(value, int):
        raise ConfigError(f'{source}: {where} must be a whole number, got {_shown(value)}')
    return int(_ranged(value, key, where, source))


def _time(value, where, source):
    if isinstance(value, dt.datetime):
        when = value
    else:
        try:
            when = dt.datetime.fromisoformat(str(value).replace('Z', '+00:00'))
        except ValueError as err:
            raise ConfigError(f'{source}: {where} is not an ISO 8601 time ({_shown(value)}); '
                              'write e.g. 2004-09-02T23:22:16-05:00') from err
    if when.utcoffset() is None:
        raise ConfigError(f'{source}: {where} {_shown(value)} has no UTC offset; add one (Z or -05:00)')
    if not _YEARS[0] <= when.year <= _YEARS[1]:
        # Also keeps astimezone off the ends of the calendar (0001-01-01T00:00+05:00 overflows).
        raise ConfigError(f'{source}: {where} {_shown(value)} is not in the years {_YEARS[0]}-{_YEARS[1]}; '
                          'check the date')
    return when.astimezone(dt.timezone.utc)


def _matrix(value, where, source):
    if not isinstance(value, list) or len(value) != 3 or not all(isinstance(row, list) and len(row) == 3
                                                                 for row in value):
        raise ConfigError(f'{source}: {where} must be a 3x3 list of numbers (three rows of three)')
    matrix = np.array([[_number(element, where, source) for element in row] for row in value])
    if np.max(np.abs(matrix)) > 1.0 + 1e-4:
        # Before the product below, which would overflow on 1e308.
        raise ConfigError(f'{source}: {where} has an element beyond [-1, 1], so it is no rotation matrix; check the '
                          'transcription')
    # Published matrices are orthonormal to 1e-5 (Table D.2): taken as printed, not re-orthonormalized.
    if np.max(np.abs(matrix @ matrix.T - np.eye(3))) > 1e-4:
        raise ConfigError(f'{source}: {where} is not a rotation matrix (|A A^T - I| > 1e-4); check the transcription')
    if np.linalg.det(matrix) < 0.0:
        raise ConfigError(f'{source}: {where} is a reflection (determinant -1), not a rotation; check the signs')
    return matrix


def _matrices(raw, source):
    """The set's named matrices, with the identity as IDENTITY_MATRIX, which no file may redefine."""
    matrices = {IDENTITY_MATRIX: np.eye(3)}
    for name, value in _mapping(raw or {}, 'matrices', source).items():
        if not isinstance(name, (str, int)) or isinstance(name, bool) or not _MATRIX_NAME.fullmatch(str(name)):
            raise ConfigError(f'{source}: matrices: name {_shown(name)} is not one word of letters, digits, '
                              '_ . + - (at most 40)')
        if str(name) in matrices:
            raise ConfigError(f'{source}: matrices.{name}: {IDENTITY_MATRIX!r} is always the identity (a run before '
                              'any alignment matrix) and each name is given once; name the matrix otherwise')
        matrices[str(name)] = _matrix(value, f'matrices.{name}', source)
    return matrices


def _check_columns(kind, columns, where, source):
    spec = KINDS[kind]
    allowed = dict(spec.required) | dict(spec.optional)
    for column in columns:
        if column in allowed:
            continue
        stem = next((column[:-len(suffix)] for suffix in _UNIT_SUFFIXES if column.endswith(suffix)), None)
        expected = [name for name in allowed if stem is not None and name.startswith(stem + '_')]
        if expected:
            raise ConfigError(f'{source}: {where}: column {column!r} has inconsistent units; {kind} takes '
                              f'{expected[0]!r} ({allowed[expected[0]]})')
        raise ConfigError(f'{source}: {where}: unknown column {column!r} for kind {kind} '
                          f'(known: {", ".join(allowed)})')
    repeated = _first_repeated(columns)
    if repeated is not None:
        # zip() into a row dict would keep the last of the two values without a word.
        raise ConfigError(f'{source}: {where}: column {repeated!r} given twice; keep one')
    missing = [name for name, _ in spec.required if name not in columns]
    if missing:
        raise ConfigError(f'{source}: {where}: missing column {missing[0]!r} ({dict(spec.required)[missing[0]]}) '
                          f'for kind {kind}')


def parse_measurement_set(text: str, source: str = '<text>') -> MeasurementSet:
    """Parse a measurement-set document into a MeasurementSet (docs/measurement-sets.md).

    Args:
        text: the YAML document.
        source: where it came from, the first word of every message.

    Returns:
        The parsed set: times in UTC, gyrf earth rates turned into TARF, every number within VALUE_RANGES.

    Raises:
        ConfigError: the first problem found, naming the table, row and fix.
    """
    document = _mapping(safe_load_limited(text, source), 'the document', source)
    unknown = [key for key in document if key not in _TOP_KEYS]
    if unknown:
        raise ConfigError(f'{source}: unknown top-level key(s) {_listed(unknown)} (allowed: '
                          f'{", ".join(sorted(_TOP_KEYS))})')
    version = document.get('measurement_set')
    if type(version) is not int or version != FORMAT_VERSION:  # true and 1.0 are not version 1
        raise ConfigError(f'{source}: not a measurement set (needs measurement_set: {FORMAT_VERSION} at the top, '
                          f'got {_shown(version)})')
    site_keys = ('latitude_deg', 'longitude_deg', 'height_m')
    raw_site = _mapping(document.get('site'), 'site (latitude_deg, longitude_deg, height_m)', source)
    for key in raw_site:
        if key not in site_keys:
            raise ConfigError(f'{source}: site: unknown key {_shown(key)} (known: {", ".join(site_keys)})')
    try:
        site = Site(*(_number(raw_site.get(key), f'site.{key}', source) for key in site_keys))
    except InvalidArgumentError as err:
        raise ConfigError(f'{source}: site: {err}') from err
    if 'epoch_utc' not in document:
        raise ConfigError(f'{source}: missing epoch_utc (the time origin of the set, ISO 8601 with offset)')
    epoch = _time(document['epoch_utc'], 'epoch_utc', source)
    night = None
    if document.get('night_utc') is not None:
        raw = document['night_utc']
        if not isinstance(raw, list) or len(raw) != 2:
            raise ConfigError(f'{source}: night_utc must be [start, end]')
        night = tuple(_time(value, 'night_utc', source) for value in raw)
        if not night[0] < night[1]:
            raise ConfigError(f'{source}: night_utc must start before it ends')
    weather = None
    if document.get('weather') is not None:
        raw = _mapping(document['weather'], 'weather', source)
        keys = ('temperature_c', 'pressure_hpa', 'relative_humidity', 'wavelength_um')
        for key in raw:
            if key not in keys:
                raise ConfigError(f'{source}: weather: unknown key {_shown(key)} (known: {", ".join(keys)})')
        try:
            weather = Weather(*(_number(raw.get(key), f'weather.{key}', source) for key in keys))
        except InvalidArgumentError as err:
            raise ConfigError(f'{source}: weather: {err}') from err
    heading = None
    if document.get('heading_deg') is not None:
        heading = _ranged(document['heading_deg'], 'heading_deg', 'heading_deg', source)
    temperature = weather.temperature_c if weather else 20.0
    if document.get('gyro_temperature_c') is not None:
        temperature = _ranged(document['gyro_temperature_c'], 'gyro_temperature_c', 'gyro_temperature_c', source)
    matrices = _matrices(document.get('matrices'), source)
    raw_tables = document.get('tables')
    if not isinstance(raw_tables, list) or not raw_tables:
        raise ConfigError(f'{source}: tables must be a non-empty list of tables')
    _check_row_count(raw_tables, source)
    context = {'site': site, 'night': night, 'weather': weather, 'heading': heading, 'matrices': matrices}
    tables = tuple(_table(raw, index, context, source) for index, raw in enumerate(raw_tables))
    families = {table.spec.family for table in tables}
    if len(families) > 1:
        raise ConfigError(f'{source}: mixes reduced kinds (star_distance, earth_rate) with alignment kinds '
                          '(turning_point, misalignment_angle); put them in separate files')
    family = families.pop()
    if any(table.kind == 'star_distance' for table in tables) and (weather is None or heading is None):
        raise ConfigError(f'{source}: star_distance tables need weather: and heading_deg: (the logbook of the night)')
    repeated = _first_repeated([table.name for table in tables])
    if repeated is not None:
        raise ConfigError(f'{source}: table name {_shown(repeated)} given twice; table names must be unique')
    return MeasurementSet(source, str(document.get('title', '')), family, site, epoch, night, weather, heading,
                          temperature, matrices, tables)


def _check_row_count(raw_tables, source):
    """Refuse more than MAX_SET_ROWS rows before any row is read: validation and fit grow with the rows."""
    rows = sum(len(raw['rows']) for raw in raw_tables if isinstance(raw, dict) and isinstance(raw.get('rows'), list))
    if rows > MAX_SET_ROWS:
        raise ConfigError(f'{source}: {rows} rows, more than the {MAX_SET_ROWS} a measurement set may have (at most '
                          f'{MAX_SET_BYTES} bytes); split it into sets')


def _table(raw, index, context, source):
    raw = _mapping(raw, f'tables[{index}]', source)
    name = raw.get('name', f'table {index + 1}')
    # The report names a table's plot after it: '../../keep' wrote outside the report folder, over a file there.
    if not isinstance(name, str) or not name.strip() or name.startswith('.') or any(c in name for c in '/\\\0'):
        raise ConfigError(f'{source}: tables[{index}]: name {_shown(name)} is not a table name; give text without '
                          '/, \\ or a leading dot, e.g. drift_corrected')
    where = f'table {_shown(name)}'
    kind = raw.get('kind')
    if not isinstance(kind, str) or kind not in KINDS:
        raise ConfigError(f'{source}: {where}: unknown kind {_shown(kind)} (known: {", ".join(KINDS)})')
    spec = KINDS[kind]
    unknown = [key for key in raw if key not in _TABLE_KEYS and key not in spec.table_keys]
    if unknown:
        raise ConfigError(f'{source}: {where}: unknown key(s) {_listed(unknown)} for kind {kind}')
    columns = raw.get('columns')
    if not isinstance(columns, list) or not all(isinstance(column, str) for column in columns):
        raise ConfigError(f'{source}: {where}: columns must be a list of column names')
    _check_columns(kind, columns, where, source)
    rows = raw.get('rows')
    if not isinstance(rows, list) or not rows:
        raise ConfigError(f'{source}: {where}: the table is empty; give at least one row')
    parsed = []
    for number, row in enumerate(rows, start=1):
        if not isinstance(row, list) or len(row) != len(columns):
            raise ConfigError(f'{source}: {where} row {number}: expected {len(columns)} values ({", ".join(columns)})')
        values = dict(zip(columns, row))
        try:
            parsed.append(_ROW_PARSERS[kind](values, context, f'{where} row {number}', source))
        except SofiaError as err:
            if isinstance(err, ConfigError):
                raise
            raise ConfigError(f'{source}: {where} row {number}: {err}') from err
    extra = {}
    if kind == 'star_distance':
        drift = raw.get('drift_removed', False)
        if not isinstance(drift, bool):
            raise ConfigError(f'{source}: {where}: drift_removed must be true or false')
        extra['drift_removed'] = drift
    if kind == 'earth_rate':
        for key in ('latitude_deg', 'heading_deg', 'elevation_deg'):
            if key not in raw:
                raise ConfigError(f'{source}: {where}: earth_rate needs {key} (the site, heading and CD elevation)')
            extra[key] = _ranged(raw[key], key, f'{where} {key}', source)
        frame = raw.get('gyro_frame', 'tarf')
        if frame not in ('tarf', 'gyrf'):
            raise ConfigError(f'{source}: {where}: gyro_frame must be tarf or gyrf, got {_shown(frame)}')
        if frame == 'gyrf':
            matrix_name = raw.get('tarf_from_gyrf')
            if not isinstance(matrix_name, str) or matrix_name not in context['matrices']:
                raise ConfigError(f'{source}: {where}: gyro_frame gyrf needs tarf_from_gyrf naming one of matrices: '
                                  f'{", ".join(context["matrices"])}')
            matrix = context['matrices'][matrix_name]
            # The reduction's "misalignment corrected" step (Table 5.7): omega_TARF = A_TARF,GYRF omega_GYRF (3.20).
            parsed = [EarthRateMean(row.label, tuple(float(v) for v in matrix @ np.array(row.rate_tarf_deg_per_h)),
                                    row.sigma_deg_per_h, row.source) for row in parsed]
    if kind in ('turning_point', 'misalignment_angle'):
        for row in parsed:
            if row.matrix not in context['matrices']:
                raise ConfigError(f'{source}: {where}: matrix {row.matrix!r} is not under matrices: (known: '
                                  f'{", ".join(context["matrices"])})')
    return Table(name, kind, tuple(parsed), str(raw.get('provenance', '')), **extra)


def _column(values, key, where, source):
    """The row's number in column ``key``, within its VALUE_RANGES."""
    return _ranged(values[key], key, f'{where} {key}', source)


def _star(value, where, source):
    """A star name or "HIP <positive number>" the catalogue knows."""
    if not isinstance(value, str):
        raise ConfigError(f'{source}: {where}: star {_shown(value)} is not a name; write a Hipparcos name or '
                          '"HIP <number>"')
    if _HIP_PREFIX.match(value) and not _HIP_DESIGNATION.fullmatch(value):
        raise ConfigError(f'{source}: {where}: {_shown(value)} is not a Hipparcos number; write "HIP" and a '
                          'positive whole number, e.g. "HIP 11767"')
    try:
        find_star(value)
    except (SofiaError, LookupError) as err:
        raise ConfigError(f'{source}: {where}: unknown star {_shown(value)}; use a Hipparcos name or '
                          '"HIP <number>"') from err
    return value


def _star_distance(values, context, where, source):
    stars = [_star(values[key], where, source) for key in ('star_1', 'star_2')]
    if find_star(stars[0]).hip == find_star(stars[1]).hip:
        raise ConfigError(f'{source}: {where}: star_1 and star_2 are the same star ({stars[0]}); a distance is between '
                          'two stars')
    times = [_time(values[key], f'{where} {key}', source) for key in ('time_1', 'time_2')]
    night = context['night']
    for key, when in zip(('time_1', 'time_2'), times):
        if night and not night[0] <= when <= night[1]:
            raise ConfigError(f'{source}: {where}: {key} {when.isoformat()} is outside the night '
                              f'{night[0].isoformat()} - {night[1].isoformat()} (night_utc); check the date and offset')
    if not times[0] < times[1]:
        raise ConfigError(f'{source}: {where}: time_2 must come after time_1')
    euler = pixels = None
    for group in (('el_arcsec', 'xel_arcsec'), ('x1_px', 'y1_px', 'x2_px', 'y2_px')):
        # Part of a group was dropped without a word (el_arcsec without xel_arcsec).
        if any(key in values for key in group) and not all(key in values for key in group):
            raise ConfigError(f'{source}: {where}: {", ".join(key for key in group if key not in values)} missing '
                              f'beside {", ".join(key for key in group if key in values)}; give all of '
                              f'{", ".join(group)} or none')
    if all(key in values for key in ('el_arcsec', 'xel_arcsec')):
        euler = tuple(_column(values, key, where, source) for key in ('el_arcsec', 'xel_arcsec', 'los_arcsec')
                      if key in values)
    if all(key in values for key in ('x1_px', 'y1_px', 'x2_px', 'y2_px')):
        pixels = tuple(_column(values, key, where, source) for key in ('x1_px', 'y1_px', 'x2_px', 'y2_px'))
    distance = _number(values['distance_arcsec'], f'{where} distance_arcsec', source)
    if not 0.0 < distance < 180.0 * 3600.0:
        raise ConfigError(f'{source}: {where}: distance_arcsec {distance:g} is not an angle between stars in arcsec')
    if euler is not None:
        # A gyro Euler-angle move: EL, XEL (corrected by the pixels, 6.7-6.8) must give the distance (4.38).
        summed = float(spherical_sum_arcsec(euler[0], euler[1]))
        if abs(summed - distance) > _EULER_TOLERANCE_ARCSEC:
            raise ConfigError(f'{source}: {where}: el_arcsec and xel_arcsec give {summed:.1f}" by eq. 4.38, not '
                              f'distance_arcsec {distance:.1f}"; give the Euler angles corrected by the pixels')
    return StarDistance(str(values.get('move', '')), stars[0], times[0], stars[1], times[1], distance,
                        _column(values, 'sigma_arcsec', where, source), euler, pixels, str(values.get('source', '')))


def _earth_rate(values, context, where, source):
    rates = tuple(_column(values, f'{axis}_deg_per_h', where, source) for axis in AXES)
    if np.linalg.norm(rates) > 100.0:
        raise ConfigError(f'{source}: {where}: rates of {np.linalg.norm(rates):.0f} deg/h are not a braked telescope '
                          "(Earth rate is 15 deg/h); check the units")
    return EarthRateMean(str(values['label']), rates, _column(values, 'sigma_deg_per_h', where, source),
                         str(values.get('source', '')))


def _turning_point(values, context, where, source):
    offset = tuple(_column(values, key, where, source) for key in ('dx_arcsec', 'dy_arcsec'))
    # The pixels and the count are the record of the reduction, not fitted: checked so a slip does not pass.
    for key in ('x_px', 'y_px'):
        if key in values:
            _column(values, key, where, source)
    if 'maneuvers' in values:
        _count(values['maneuvers'], 'maneuvers', f'{where} maneuvers', source)
    return TurningPoint(str(values['matrix']), offset, _column(values, 'sigma_arcsec', where, source),
                        str(values.get('source', '')))


def _misalignment_angle(values, context, where, source):
    axis = str(values['axis']).lower()
    if axis not in ('u', 'v'):
        raise ConfigError(f'{source}: {where}: axis must be u or v (the maneuver axis of Table 6.4), '
                          f'got {_shown(axis)}')
    return MisalignmentAngle(str(values['matrix']), axis, _column(values, 'angle_arcmin', where, source),
                             _column(values, 'sigma_arcmin', where, source), str(values.get('source', '')))


_ROW_PARSERS = {'star_distance': _star_distance, 'earth_rate': _earth_rate, 'turning_point': _turning_point,
                'misalignment_angle': _misalignment_angle}

