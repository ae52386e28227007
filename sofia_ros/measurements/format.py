"""Measurement sets: the records of reduced observables a user fills from their own logs (docs/measurement-sets.md).

A measurement set is one YAML file: the site, time origin, night, weather and heading of the
logbook, the implemented alignment matrices it refers to, and tables of one *kind* each. The
kinds, their columns (units in the names) and the effects each can see are declared here; the
parser is measurements.validate, the physics measurements.predict.

Two families of kinds. *Reduced* kinds (star_distance, earth_rate) hold observables after the
TASCU's alignment matrix and the stated reductions: a model's gyro terms there are the errors the
reduction left in, so their fitted terms start at zero. *Alignment* kinds (turning_point,
misalignment_angle) hold the result of an alignment maneuver under a named implemented matrix: the
model's gyro_misalignment there is the mounting itself, fitted from the model's values. One file
holds one family.
"""

from __future__ import annotations

import datetime as dt
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from sofia_ros.config import MAX_CONFIG_BYTES

if TYPE_CHECKING:  # named in annotations only: reading the format needs no ERFA
    from sofia_ros.sky.places import Site, Weather

__all__ = ['FORMAT_VERSION', 'KINDS', 'KindSpec', 'StarDistance', 'EarthRateMean', 'TurningPoint',
           'MisalignmentAngle', 'Table', 'MeasurementSet', 'REDUCED', 'ALIGNMENT', 'MAX_SET_BYTES', 'MAX_SET_ROWS',
           'VALUE_RANGES', 'IDENTITY_MATRIX', 'Row']

FORMAT_VERSION = 1
REDUCED = 'reduced'
ALIGNMENT = 'alignment'
#: The matrix every set knows: the identity, a run before any alignment matrix.
IDENTITY_MATRIX = 'none'

#: A set is a few kB (the thesis' largest, 5.4 kB); the YAML reader takes no more than this anyway.
MAX_SET_BYTES = MAX_CONFIG_BYTES
#: Rows of all tables together: the thesis' tables hold at most 20; 2000 star distances compare in about 4 s.
MAX_SET_ROWS = 2000

_SIGMA_WHY = 'below 1e-06" the fit\'s weights overflow, above 1e+04" a row weighs nothing'
_EULER = (-648000.0, 648000.0, 'arcsec', 'an Euler angle of at most 180 deg')
_PIXEL = (-10000.0, 10000.0, 'px', 'a position on a detector')
_RATE = (-100.0, 100.0, 'deg/h', 'not a braked telescope: Earth rate is 15 deg/h')
_OFFSET = (-36000.0, 36000.0, 'arcsec', 'a turning point within 10 deg of the TARF origin')
#: name -> (lowest, highest, unit, why) of every number of a set but the site, weather and distance (checked
#: where they are built): outside is a typo or a unit slip, which would pass as a result (a heading of 1e308
#: deg) or overflow the fit (a sigma of 1e-300").
VALUE_RANGES = {
    'heading_deg': (-360.0, 360.0, 'deg', 'a true heading'),
    'gyro_temperature_c': (-90.0, 100.0, 'C', 'a gyro box on the ground or in flight'),
    'latitude_deg': (-90.0, 90.0, 'deg', 'a latitude'),
    'elevation_deg': (-90.0, 90.0, 'deg', 'a telescope elevation'),
    'el_arcsec': _EULER, 'xel_arcsec': _EULER, 'los_arcsec': _EULER,
    'x1_px': _PIXEL, 'y1_px': _PIXEL, 'x2_px': _PIXEL, 'y2_px': _PIXEL, 'x_px': _PIXEL, 'y_px': _PIXEL,
    'el_deg_per_h': _RATE, 'xel_deg_per_h': _RATE, 'los_deg_per_h': _RATE,
    'dx_arcsec': _OFFSET, 'dy_arcsec': _OFFSET,
    'angle_arcmin': (-600.0, 600.0, 'arcmin', 'a misalignment within 10 deg'),
    'sigma_arcsec': (1e-6, 1e4, 'arcsec', _SIGMA_WHY),
    'sigma_arcmin': (1e-6 / 60.0, 1e4 / 60.0, 'arcmin', _SIGMA_WHY),
    'sigma_deg_per_h': (1e-6, 1e4, 'deg/h', 'below 1e-06 deg/h (1e-06"/s) the fit\'s weights overflow, above '
                        '1e+04 deg/h a row weighs nothing'),
    'maneuvers': (1, 10000, 'maneuvers', 'a whole number of alignment maneuvers'),
}


@dataclass(frozen=True)
class KindSpec:
    """One observable kind: its columns (name -> unit), optional columns, table keys, what it sees."""

    name: str
    family: str
    description: str
    #: (column, unit) pairs
    required: tuple[tuple[str, str], ...]
    optional: tuple[tuple[str, str], ...]
    table_keys: tuple[str, ...]
    #: effect -> why this kind's predictions depend on it
    sees: dict[str, str]
    #: effect -> why not (the default reason covers the rest of the catalogue)
    blind: dict[str, str]
    default_blind_reason: str
    #: observables (suffixes) each row yields
    axes: tuple[str, ...] = ('',)


_DISTANCE_BLIND = {
    'gyro_misalignment': 'a turn of the gyro axes keeps the rotation angle: a distance sees a residual misalignment '
                         'only through the LOS share of a move, at second order (the TASCU matrix and 6.5 removed it)',
    'imager_boresight_offset': 'both stars are on the same boresight: an imager offset cancels in the distance',
    'imager_rotation_of_field': 'both stars are on the same boresight: a field rotation cancels in the distance',
    'imager_scale_error': 'both stars are on the same boresight: an image scale cancels in the distance',
    'hipo_fiducial_error': 'the reduction refers both stars to one detector point: a fiducial error cancels',
    'focal_plane_flexure': 'a reduced distance carries no boresight position per elevation (6.2: < 1.1" over 23-60 deg)',
    'imager_flexure': 'a reduced distance carries no boresight position per elevation (6.2: < 1.1" over 23-60 deg)',
    'fpi_internal_flexure': 'a reduced distance carries no boresight position per elevation (6.2: < 1.1" over 23-60 deg)',
    'timestamp_offset': 'the telescope is held still at both times: a clock offset moves no star',
    'seeing': 'noise, averaged in the reduction; it sets the sigma column',
    'gyro_noise': 'noise; it sets the sigma column',
    'vibration_lines': 'lines average out over a move',
    'accelerometer_bias': 'no accelerometer data in a distance',
    'accelerometer_misalignment': 'no accelerometer data in a distance',
    'heading_error': 'the attitude at each star comes from the star itself, not from the heading',
}

#: Rate offsets that a drift correction (6.3-6.4: the drift measured on the held star) removes.
DRIFT_EFFECTS = ('gyro_bias', 'gyro_bias_drift', 'tracker_drift', 'los_oscillation')

KINDS = {
    'star_distance': KindSpec(
        'star_distance', REDUCED,
        'angular distance of two stars measured with the gyros between two holds (6.3, Table 6.7)',
        required=(('star_1', 'name'), ('time_1', 'ISO 8601 with offset'), ('star_2', 'name'),
                  ('time_2', 'ISO 8601 with offset'), ('distance_arcsec', 'arcsec'), ('sigma_arcsec', 'arcsec')),
        optional=(('move', 'label'), ('el_arcsec', 'arcsec'), ('xel_arcsec', 'arcsec'), ('los_arcsec', 'arcsec'),
                  ('x1_px', 'px'), ('y1_px', 'px'), ('x2_px', 'px'), ('y2_px', 'px'), ('source', 'text')),
        table_keys=('drift_removed',),
        sees={'gyro_scale_factor': 'scales the measured rotation (2.4.1)',
              'gyro_axis_swap': 'the swapped calibrations scale EL and XEL oppositely (6.3)',
              'earth_rotation': 'the gyros measure the move in inertial space (4.1)',
              'atmospheric_refraction': 'raises each star by its refraction at its time (6.2)',
              'gyro_bias': 'integrates over the time between the holds unless the drift is removed',
              'gyro_bias_drift': 'integrates over the time between the holds unless the drift is removed',
              'tracker_drift': 'integrates over the time between the holds unless the drift is removed',
              'los_oscillation': 'integrates over the time between the holds unless the drift is removed'},
        blind=_DISTANCE_BLIND,
        default_blind_reason='star_distance predictions do not depend on it'),
    'earth_rate': KindSpec(
        'earth_rate', REDUCED,
        'mean gyro rates of a braked telescope at a stated site, heading and elevation (5.2.4, Table 5.7)',
        required=(('label', 'name'), ('el_deg_per_h', 'deg/h'), ('xel_deg_per_h', 'deg/h'),
                  ('los_deg_per_h', 'deg/h'), ('sigma_deg_per_h', 'deg/h')),
        optional=(('source', 'text'),),
        table_keys=('latitude_deg', 'heading_deg', 'elevation_deg', 'gyro_frame', 'tarf_from_gyrf'),
        sees={'gyro_bias': 'adds to each axis (5.2.4)',
              'heading_error': 'turns Earth rate between EL, XEL and LOS (4.1-4.3)',
              'gyro_scale_factor': 'scales the Earth rate each axis senses',
              'gyro_axis_swap': 'scales and biases EL and XEL oppositely',
              'gyro_misalignment': 'turns the Earth rate between the axes',
              'earth_rotation': 'is the measured rate (4.1)'},
        blind={'gyro_bias_drift': 'a mean rate does not show a ramp',
               'los_oscillation': 'a mean over many periods does not show it',
               'vibration_lines': 'a mean does not show lines',
               'gyro_noise': 'noise; it sets the sigma column'},
        default_blind_reason='a braked telescope\'s mean rate does not depend on it',
        axes=('el', 'xel', 'los')),
    'turning_point': KindSpec(
        'turning_point', ALIGNMENT,
        'LOS turning point on HIPO against the TARF origin under an implemented matrix (3.10, Tables 6.1, 6.2)',
        required=(('matrix', 'name'), ('dx_arcsec', 'arcsec'), ('dy_arcsec', 'arcsec'), ('sigma_arcsec', 'arcsec')),
        optional=(('x_px', 'px'), ('y_px', 'px'), ('maneuvers', 'count'), ('source', 'text')),
        table_keys=(),
        sees={'gyro_misalignment': 'the LOS tilt left by the implemented matrix puts the turning point off the origin (3.10)'},
        blind={'hipo_fiducial_error': 'the reduction measured against the 2004 fiducials it names; not modelled here'},
        default_blind_reason='an alignment result under a known matrix depends only on the gyro mounting',
        axes=('x', 'y')),
    'misalignment_angle': KindSpec(
        'misalignment_angle', ALIGNMENT,
        'EL/XEL misalignment angle beta under an implemented matrix (3.16-3.19, Table 6.4)',
        required=(('matrix', 'name'), ('axis', 'u|v'), ('angle_arcmin', 'arcmin'), ('sigma_arcmin', 'arcmin')),
        optional=(('source', 'text'),),
        table_keys=(),
        sees={'gyro_misalignment': 'the turn about LOS left by the implemented matrix is beta (3.18-3.19)'},
        blind={},
        default_blind_reason='an alignment result under a known matrix depends only on the gyro mounting'),
}


@dataclass(frozen=True)
class StarDistance:
    """One move: two stars at their times and the measured distance with its sigma (Table 6.7, D.3, D.6)."""

    move: str
    star_1: str
    time_1_utc: dt.datetime
    star_2: str
    time_2_utc: dt.datetime
    distance_arcsec: float
    sigma_arcsec: float
    #: EL, XEL (and LOS) Euler angles of the move [arcsec]
    euler_arcsec: tuple[float, ...] | None = None
    #: x1, y1, x2, y2 [px]
    pixels_px: tuple[float, float, float, float] | None = None
    source: str = ''


@dataclass(frozen=True)
class EarthRateMean:
    """Mean EL, XEL, LOS rates in TARF of one record (Table 5.7), sigma per axis."""

    label: str
    rate_tarf_deg_per_h: tuple[float, float, float]
    sigma_deg_per_h: float
    source: str = ''


@dataclass(frozen=True)
class TurningPoint:
    """LOS turning point against the TARF origin along HIPO X, Y under an implemented matrix (Tables 6.1, 6.2)."""

    matrix: str
    #: dx, dy [arcsec]
    offset_arcsec: tuple[float, float]
    sigma_arcsec: float
    source: str = ''


@dataclass(frozen=True)
class MisalignmentAngle:
    """Misalignment angle beta from the U or V maneuvers under an implemented matrix (Table 6.4)."""

    matrix: str
    axis: str
    angle_arcmin: float
    sigma_arcmin: float
    source: str = ''


#: One row of a table, of its kind's record type.
Row = StarDistance | EarthRateMean | TurningPoint | MisalignmentAngle


@dataclass(frozen=True)
class Table:
    """One table of a set: its name, kind, reduction flags and geometry, provenance, and rows."""

    name: str
    kind: str
    rows: tuple[Row, ...]
    provenance: str
    drift_removed: bool = False
    latitude_deg: float | None = None
    heading_deg: float | None = None
    elevation_deg: float | None = None

    @property
    def spec(self) -> KindSpec:
        """The KindSpec of this table."""
        return KINDS[self.kind]

    def measured(self) -> np.ndarray:
        """The measured values (one per observable of each row), in the kind's units.

        Returns:
            One value per observable_names() entry, row by row (axes within a row).
        """
        if self.kind == 'star_distance':
            return np.array([row.distance_arcsec for row in self.rows])
        if self.kind == 'earth_rate':
            return np.array([row.rate_tarf_deg_per_h for row in self.rows]).ravel()
        if self.kind == 'turning_point':
            return np.array([row.offset_arcsec for row in self.rows]).ravel()
        return np.array([row.angle_arcmin for row in self.rows])

    def sigma(self) -> np.ndarray:
        """The stated 1-sigma of each measured value, same order and units as measured().

        Returns:
            One sigma per measured value (a row's sigma repeated over its axes).
        """
        if self.kind == 'star_distance':
            return np.array([row.sigma_arcsec for row in self.rows])
        if self.kind == 'earth_rate':
            return np.repeat([row.sigma_deg_per_h for row in self.rows], 3)
        if self.kind == 'turning_point':
            return np.repeat([row.sigma_arcsec for row in self.rows], 2)
        return np.array([row.sigma_arcmin for row in self.rows])

    def observable_names(self) -> list[str]:
        """'<kind>' or '<kind>.<axis>' of each measured value.

        Returns:
            One name per measured value, same order as measured().
        """
        axes = self.spec.axes
        if self.kind == 'misalignment_angle':
            return [f'{self.kind}.{row.axis}' for row in self.rows]
        return [self.kind if axis == '' else f'{self.kind}.{axis}' for _ in self.rows for axis in axes]


@dataclass(frozen=True)
class MeasurementSet:
    """A parsed measurement set: logbook (site, time origin, night, weather, heading), matrices, tables."""

    source: str
    title: str
    family: str
    site: Site
    epoch_utc: dt.datetime
    night_utc: tuple[dt.datetime, dt.datetime] | None
    weather: Weather | None
    heading_deg: float | None
    gyro_temperature_c: float
    #: name -> implemented alignment matrix (3x3), IDENTITY_MATRIX included
    matrices: dict[str, np.ndarray]
    tables: tuple[Table, ...]
