"""Earth rate sensed by the gyros (eqs. 4.1-4.3) against Table 5.7."""

import numpy as np
import pytest

from sofia_ros.earth_rate import best_fit_heading_deg, earth_rate_tarf_deg_per_h, earth_rate_tarf_rad_per_s
from sofia_ros.errors import InvalidArgumentError

# Table 5.3 / 5.2.1: latitude N 34.9368 deg, CD elevation 40.1077 deg. Section 5.2.4 prints
# 40.1007 deg, but only 40.1077 reproduces the LOS value 0.0059 deg/h of Table 5.7.
LATITUDE_DEG = 34.9368
ELEVATION_DEG = 40.1077
TOLERANCE_DEG_PER_H = 0.0005


def test_table_5_7_theoretical_row_for_gps_heading_324_deg():
    expected = [9.9755, -11.2571, 0.0059]  # Table 5.7, "GPS measured Heading = 324 deg"
    rates = earth_rate_tarf_deg_per_h(LATITUDE_DEG, 324.0, ELEVATION_DEG)
    np.testing.assert_allclose(rates, expected, atol=TOLERANCE_DEG_PER_H)
    assert np.linalg.norm(rates) == pytest.approx(15.0411, abs=1e-9)


def test_table_5_7_least_squares_heading_row_is_for_327_2_deg():
    # Table 5.7 labels this row "Heading = 327.7 deg"; its values (10.3645, -10.8911, 0.4404)
    # follow from 4.1-4.3 at 327.2 deg. At 327.7 deg the EL rate would be 10.4225 deg/h.
    expected = [10.3645, -10.8911, 0.4404]
    np.testing.assert_allclose(earth_rate_tarf_deg_per_h(LATITUDE_DEG, 327.2, ELEVATION_DEG), expected,
                               atol=TOLERANCE_DEG_PER_H)
    assert earth_rate_tarf_deg_per_h(LATITUDE_DEG, 327.7, ELEVATION_DEG)[0] - expected[0] > 0.05


def test_heading_search_of_5_2_4_finds_327_2_deg_for_the_measured_average():
    # Table 5.7 "Misalignment corrected average" of all test cases
    measured = [10.3002, -10.7287, 0.3495]
    heading = best_fit_heading_deg(measured, LATITUDE_DEG, ELEVATION_DEG)
    assert heading == pytest.approx(327.2, abs=0.05)
    residual = np.asarray(measured) - earth_rate_tarf_deg_per_h(LATITUDE_DEG, 327.2, ELEVATION_DEG)
    # Table 5.7 "Deviations": -0.0643, 0.1624, -0.0909 deg/h at the printed rounding
    np.testing.assert_allclose(residual, [-0.0643, 0.1624, -0.0909], atol=0.001)


def test_rad_per_s_is_the_same_vector():
    deg_per_h = earth_rate_tarf_deg_per_h(LATITUDE_DEG, 324.0, ELEVATION_DEG)
    rad_per_s = earth_rate_tarf_rad_per_s(LATITUDE_DEG, 324.0, ELEVATION_DEG)
    np.testing.assert_allclose(rad_per_s, np.radians(deg_per_h) / 3600.0)


def test_broadcasts_over_elevations():
    rates = earth_rate_tarf_deg_per_h(LATITUDE_DEG, 324.0, np.array([20.0, 40.0, 60.0]))
    assert rates.shape == (3, 3)
    np.testing.assert_allclose(np.linalg.norm(rates, axis=-1), 15.0411)


def test_nan_heading_is_refused():
    with pytest.raises(InvalidArgumentError, match='heading_deg contains NaN'):
        earth_rate_tarf_deg_per_h(LATITUDE_DEG, float('nan'), ELEVATION_DEG)


def test_measured_rate_needs_three_axes():
    with pytest.raises(InvalidArgumentError, match=r'measured_rate_deg_per_h must have shape 3'):
        best_fit_heading_deg([1.0, 2.0], LATITUDE_DEG, ELEVATION_DEG)
