"""Parse and validate a measurement-set YAML file: one-line ConfigErrors naming the table, row and fix."""

from __future__ import annotations

import datetime as dt
from pathlib import Path

import numpy as np
import yaml

from sofia_ros.errors import ConfigError, InvalidArgumentError, SofiaError
from sofia_ros.frames import AXES
from sofia_ros.measurements.format import (
    FORMAT_VERSION,
    KINDS,
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

def is_measurement_set_path(path):
    """True for a file path ending .yaml or .yml (a bag is a directory)."""
    return str(path).lower().endswith(('.yaml', '.yml'))

def load_measurement_set(path):
    """Read and validate a measurement set; ConfigError (one line) on any problem."""
    path = Path(path)
    try:
        text = path.read_text()
    except OSError as err:
        raise ConfigError(f'cannot read measurement set {path}: {err.strerror}; check the path') from err
    return parse_measurement_set(text, str(path))

def _mapping(value, where, source):
    if not isinstance(value, dict):
        raise ConfigError(f'{source}: {where} must be a mapping')
    return value

def _number(value, where, source):
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not np.isfinite(value):
        raise ConfigError(f'{source}: {where} must be a finite number, got {value!r}')
    return float(value)

def _time(value, where, source):
    if isinstance(value, dt.datetime):
        when = value
    else:
        try:
            when = dt.datetime.fromisoformat(str(value).replace('Z', '+00:00'))
        except ValueError as err:
            raise ConfigError(f'{source}: {where} is not an ISO 8601 time ({value!r}); '
                              'write e.g. 2004-09-02T23:22:16-05:00') from err
    if when.utcoffset() is None:
        raise ConfigError(f'{source}: {where} {value!r} has no UTC offset; add one (Z or -05:00)')
    return when.astimezone(dt.timezone.utc)

def _matrix(value, where, source):
    try:
        matrix = np.array(value, dtype=float)
    except (TypeError, ValueError) as err:
        raise ConfigError(f'{source}: {where} must be a 3x3 list of numbers') from err
    if matrix.shape != (3, 3) or not np.all(np.isfinite(matrix)):
        raise ConfigError(f'{source}: {where} must be a 3x3 list of finite numbers')
    if np.max(np.abs(matrix @ matrix.T - np.eye(3))) > 1e-4:
        raise ConfigError(f'{source}: {where} is not a rotation matrix (|A A^T - I| > 1e-4); check the transcription')
    return matrix

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
    missing = [name for name, _ in spec.required if name not in columns]
    if missing:
        raise ConfigError(f'{source}: {where}: missing column {missing[0]!r} ({dict(spec.required)[missing[0]]}) '
                          f'for kind {kind}')

def parse_measurement_set(text, source='<text>'):
    """Parse a measurement-set document into a MeasurementSet (docs/measurement-sets.md)."""
    try:
        document = yaml.safe_load(text)
    except yaml.YAMLError as err:
        raise ConfigError(f'{source}: not valid YAML ({str(err).splitlines()[0]}); fix the syntax') from err
    document = _mapping(document, 'the document', source)
    unknown = sorted(set(document) - _TOP_KEYS)
    if unknown:
        raise ConfigError(f'{source}: unknown top-level key(s) {", ".join(unknown)} (allowed: '
                          f'{", ".join(sorted(_TOP_KEYS))})')
    if document.get('measurement_set') != FORMAT_VERSION:
        raise ConfigError(f'{source}: not a measurement set (needs measurement_set: {FORMAT_VERSION} at the top)')
    site_keys = ('latitude_deg', 'longitude_deg', 'height_m')
    raw_site = _mapping(document.get('site'), 'site (latitude_deg, longitude_deg, height_m)', source)
    for key in raw_site:
        if key not in site_keys:
            raise ConfigError(f'{source}: site: unknown key {key!r} (known: {", ".join(site_keys)})')
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
                raise ConfigError(f'{source}: weather: unknown key {key!r} (known: {", ".join(keys)})')
        try:
            weather = Weather(*(_number(raw.get(key), f'weather.{key}', source) for key in keys))
        except InvalidArgumentError as err:
            raise ConfigError(f'{source}: weather: {err}') from err
    heading = None if document.get('heading_deg') is None else _number(document['heading_deg'], 'heading_deg', source)
    temperature = weather.temperature_c if weather else 20.0
    if document.get('gyro_temperature_c') is not None:
        temperature = _number(document['gyro_temperature_c'], 'gyro_temperature_c', source)
    matrices = {'none': np.eye(3)}
    for name, value in (_mapping(document.get('matrices') or {}, 'matrices', source)).items():
        matrices[str(name)] = _matrix(value, f'matrices.{name}', source)
    raw_tables = document.get('tables')
    if not isinstance(raw_tables, list) or not raw_tables:
        raise ConfigError(f'{source}: tables must be a non-empty list of tables')
    context = {'site': site, 'night': night, 'weather': weather, 'heading': heading, 'matrices': matrices}
    tables = tuple(_table(raw, index, context, source) for index, raw in enumerate(raw_tables))
    families = {table.spec.family for table in tables}
    if len(families) > 1:
        raise ConfigError(f'{source}: mixes reduced kinds (star_distance, earth_rate) with alignment kinds '
                          '(turning_point, misalignment_angle); put them in separate files')
    family = families.pop()
    if any(table.kind == 'star_distance' for table in tables) and (weather is None or heading is None):
        raise ConfigError(f'{source}: star_distance tables need weather: and heading_deg: (the logbook of the night)')
    names = [table.name for table in tables]
    if len(set(names)) != len(names):
        raise ConfigError(f'{source}: table names must be unique, got {names}')
    return MeasurementSet(source, str(document.get('title', '')), family, site, epoch, night, weather, heading,
                          temperature, matrices, tables)

def _table(raw, index, context, source):
    raw = _mapping(raw, f'tables[{index}]', source)
    name = str(raw.get('name', f'table {index + 1}'))
    where = f'table {name!r}'
    kind = raw.get('kind')
    if kind not in KINDS:
        raise ConfigError(f'{source}: {where}: unknown kind {kind!r} (known: {", ".join(KINDS)})')
    spec = KINDS[kind]
    unknown = sorted(set(raw) - _TABLE_KEYS - set(spec.table_keys))
    if unknown:
        raise ConfigError(f'{source}: {where}: unknown key(s) {", ".join(unknown)} for kind {kind}')
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
            extra[key] = _number(raw[key], f'{where} {key}', source)
        frame = raw.get('gyro_frame', 'tarf')
        if frame not in ('tarf', 'gyrf'):
            raise ConfigError(f'{source}: {where}: gyro_frame must be tarf or gyrf, got {frame!r}')
        if frame == 'gyrf':
            matrix_name = raw.get('tarf_from_gyrf')
            if matrix_name not in context['matrices']:
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

def _sigma(value, where, source):
    sigma = _number(value, where, source)
    if sigma <= 0.0:
        raise ConfigError(f'{source}: {where} must be positive, got {sigma:g}')
    return sigma

def _star_distance(values, context, where, source):
    stars = []
    for key in ('star_1', 'star_2'):
        try:
            find_star(values[key])
            stars.append(str(values[key]))
        except (SofiaError, LookupError) as err:
            raise ConfigError(f'{source}: {where}: unknown star {values[key]!r}; use a Hipparcos name or '
                              '"HIP <number>"') from err
    times = [_time(values[key], f'{where} {key}', source) for key in ('time_1', 'time_2')]
    night = context['night']
    for key, when in zip(('time_1', 'time_2'), times):
        if night and not night[0] <= when <= night[1]:
            raise ConfigError(f'{source}: {where}: {key} {when.isoformat()} is outside the night '
                              f'{night[0].isoformat()} - {night[1].isoformat()} (night_utc); check the date and offset')
    if not times[0] < times[1]:
        raise ConfigError(f'{source}: {where}: time_2 must come after time_1')
    euler = pixels = None
    if all(key in values for key in ('el_arcsec', 'xel_arcsec')):
        euler = tuple(_number(values[key], f'{where} {key}', source) for key in ('el_arcsec', 'xel_arcsec', 'los_arcsec')
                      if key in values)
    if all(key in values for key in ('x1_px', 'y1_px', 'x2_px', 'y2_px')):
        pixels = tuple(_number(values[key], f'{where} {key}', source) for key in ('x1_px', 'y1_px', 'x2_px', 'y2_px'))
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
                        _sigma(values['sigma_arcsec'], f'{where} sigma_arcsec', source), euler, pixels,
                        str(values.get('source', '')))

def _earth_rate(values, context, where, source):
    rates = tuple(_number(values[f'{axis}_deg_per_h'], f'{where} {axis}_deg_per_h', source)
                  for axis in AXES)
    if np.linalg.norm(rates) > 100.0:
        raise ConfigError(f'{source}: {where}: rates of {np.linalg.norm(rates):.0f} deg/h are not a braked telescope '
                          "(Earth rate is 15 deg/h); check the units")
    return EarthRateMean(str(values['label']), rates, _sigma(values['sigma_deg_per_h'], f'{where} sigma_deg_per_h',
                                                              source), str(values.get('source', '')))

def _turning_point(values, context, where, source):
    offset = tuple(_number(values[key], f'{where} {key}', source) for key in ('dx_arcsec', 'dy_arcsec'))
    return TurningPoint(str(values['matrix']), offset, _sigma(values['sigma_arcsec'], f'{where} sigma_arcsec', source),
                        str(values.get('source', '')))

def _misalignment_angle(values, context, where, source):
    axis = str(values['axis']).lower()
    if axis not in ('u', 'v'):
        raise ConfigError(f'{source}: {where}: axis must be u or v (the maneuver axis of Table 6.4), got {axis!r}')
    return MisalignmentAngle(str(values['matrix']), axis, _number(values['angle_arcmin'], f'{where} angle_arcmin',
                                                                 source),
                             _sigma(values['sigma_arcmin'], f'{where} sigma_arcmin', source),
                             str(values.get('source', '')))

_ROW_PARSERS = {'star_distance': _star_distance, 'earth_rate': _earth_rate, 'turning_point': _turning_point,
                'misalignment_angle': _misalignment_angle}

