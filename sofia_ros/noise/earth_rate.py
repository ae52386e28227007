"""The Earth-rate table of a stability record in the layout of Table 5.7 (section 5.2.4, eqs. 4.1-4.3).

Rows: the GYRF mean rates as measured; the same turned into TARF with a known A_TARF,GYRF
(eq. 3.20, the "misalignment corrected average" of Table 5.7, which used the latest gyro alignment
matrix: Table D.2 #5 reproduces its row to 1e-4 deg/h); the theoretical rates at the assumed
heading; their differences (the apparent biases); and the same at the heading that minimizes the
squared biases (the heading search of 5.2.4).

On a stationary record a heading error and constant gyro biases are degenerate: any heading
explains the means exactly with biases equal to the differences, so the search can only pick the
heading with the smallest biases. The thesis prints that row as "heading = 327.7 deg"; its values
are eqs. 4.1-4.3 at 327.20 deg (to 5e-5 deg/h), and the search over Table 5.7's own corrected
average finds 327.18 deg: 327.7 is a slip.
"""

from __future__ import annotations

from typing import TypedDict

import numpy as np
import numpy.typing as npt

from sofia_ros.earth_rate import best_fit_heading_deg, earth_rate_tarf_deg_per_h
from sofia_ros.frames import AXES
from sofia_ros.validate import finite_array, orthonormal_dcm

__all__ = ['DEGENERATE_PAIR', 'earth_rate_table', 'AxisRates', 'AbsoluteRates', 'EarthRateTable']

#: Effects a stationary record cannot tell apart (5.2.4).
DEGENERATE_PAIR = ('heading_error', 'gyro_bias')


class AxisRates(TypedDict):
    """One row of Table 5.7: a rate per TARF (or GYRF) axis [deg/h]."""

    el: float
    xel: float
    los: float


class AbsoluteRates(TypedDict):
    """The length of the measured and the theoretical rate vectors [deg/h]."""

    measured: float
    theoretical: float


class EarthRateTable(TypedDict):
    """Table 5.7 of one record (the earth_rate_deg_per_h object of `sofia noise --json`, docs/noise.md)."""

    measured: AxisRates
    #: None where no A_TARF,GYRF was given
    misalignment_corrected: AxisRates | None
    theoretical: AxisRates
    deviation: AxisRates
    heading_deg: float
    best_fit_heading_deg: float
    heading_error_deg: float
    theoretical_at_best_fit_heading: AxisRates
    deviation_at_best_fit_heading: AxisRates
    absolute_deg_per_h: AbsoluteRates


def _row(values: np.ndarray) -> AxisRates:
    return {axis: float(value) for axis, value in zip(AXES, values)}


def earth_rate_table(measured_gyrf_deg_per_h: npt.ArrayLike, latitude_deg: float, heading_deg: float,
                     elevation_deg: float, tarf_from_gyrf: npt.ArrayLike | None = None) -> EarthRateTable:
    """Table 5.7 of one record: means, misalignment-corrected means, theory and biases at two headings (5.2.4).

    Args:
        measured_gyrf_deg_per_h: the record's mean GYRF rates el, xel, los [deg/h].
        latitude_deg: the site's latitude [deg].
        heading_deg: the assumed true heading [deg].
        elevation_deg: the telescope's elevation [deg].
        tarf_from_gyrf: A_TARF,GYRF that corrects the means (3x3); None to take them as TARF.

    Returns:
        The rows of Table 5.7 per axis, the headings and the absolute rates ('misalignment_corrected' None without
        a matrix).

    Raises:
        InvalidArgumentError: means not three finite numbers, or a matrix that is no rotation.
    """
    measured = finite_array('measured_gyrf_deg_per_h', measured_gyrf_deg_per_h, shape=(3,))
    corrected = measured if tarf_from_gyrf is None else orthonormal_dcm('tarf_from_gyrf', tarf_from_gyrf) @ measured
    theoretical = earth_rate_tarf_deg_per_h(latitude_deg, heading_deg, elevation_deg)
    best_heading_deg = best_fit_heading_deg(corrected, latitude_deg, elevation_deg)
    best = earth_rate_tarf_deg_per_h(latitude_deg, best_heading_deg, elevation_deg)
    table: EarthRateTable = {
        'measured': _row(measured),
        'misalignment_corrected': None if tarf_from_gyrf is None else _row(corrected),
        'theoretical': _row(theoretical),
        'deviation': _row(corrected - theoretical),
        'heading_deg': float(heading_deg),
        'best_fit_heading_deg': best_heading_deg,
        'heading_error_deg': float((best_heading_deg - heading_deg + 180.0) % 360.0 - 180.0),
        'theoretical_at_best_fit_heading': _row(best),
        'deviation_at_best_fit_heading': _row(corrected - best),
        'absolute_deg_per_h': {'measured': float(np.linalg.norm(measured)),
                               'theoretical': float(np.linalg.norm(theoretical))},
    }
    return table
