"""Stone's refraction model (4.33-4.35) and its inputs, against ERFA and the thesis' 4.3.2."""

import numpy as np
import pytest

from sofia_ros.errors import InvalidArgumentError
from sofia_ros.sky.refraction import (
    air_refractivity,
    apparent_altitude_deg,
    erfa_refraction_arcsec,
    gravity_ratio,
    saturation_vapour_pressure_hpa,
    scale_height_ratio,
    stone_refraction_arcsec,
    stone_refraction_from_topocentric_arcsec,
)

# Reference conditions of 4.3.2 and 6.3 (Waco, 2004-09-02 24:00 CDT, NCDC), site of docs/conventions.md (Data).
WACO = dict(temperature_c=22.8, pressure_hpa=996.3, relative_humidity=0.74, wavelength_um=0.55)
WACO_SITE = dict(latitude_deg=31.638, height_m=144.0)


def stone(zenith_deg, **changes):
    conditions = {**WACO, **WACO_SITE, **changes}
    return stone_refraction_arcsec(zenith_deg, **conditions)


def test_owens_dry_air_matches_edlen_standard_air():
    # Edlen (1966) dispersion of standard air (15 C, 1013.25 hPa, dry):
    # (n-1) 1e8 = 8342.13 + 2406030/(130 - s^2) + 15997/(38.9 - s^2). Independent of Owens.
    for wavelength_um in (0.4, 0.55, 0.7, 1.0):
        sigma2 = wavelength_um**-2
        edlen = 1e-8 * (8342.13 + 2406030.0 / (130.0 - sigma2) + 15997.0 / (38.9 - sigma2))
        ours = air_refractivity(15.0, 1013.25, 0.0, wavelength_um)
        assert ours == pytest.approx(edlen, rel=1e-4)


def test_refractivity_at_thesis_normal_conditions():
    # 4.3.2: n0 = 1.0002927 for dry air at 550 nm, 101325 Pa, 273.15 K (after eq. 4.32).
    # Owens gives 2.9314e-4, 0.15 % higher than the thesis' value.
    assert air_refractivity(0.0, 1013.25, 0.0, 0.55) == pytest.approx(2.927e-4, rel=2e-3)


def test_saturation_vapour_pressure():
    # Saturation over water: 23.39 hPa at 20 C and 1013.25 hPa at 100 C (steam tables).
    assert saturation_vapour_pressure_hpa(20.0) == pytest.approx(23.39, rel=5e-3)
    assert saturation_vapour_pressure_hpa(100.0) == pytest.approx(1013.25, rel=5e-3)


def test_kappa_and_beta():
    # 4.34: kappa = 1 at the equator at sea level, grows with latitude (flattening).
    assert gravity_ratio(0.0, 0.0) == 1.0
    assert gravity_ratio(31.638, 144.0) == pytest.approx(1.0014089, abs=1e-7)
    # 4.35: beta = 0.001254 at 0 C.
    assert scale_height_ratio(0.0) == pytest.approx(0.001254, abs=1e-12)
    assert scale_height_ratio(22.8) == pytest.approx(0.001254 * 295.95 / 273.15, rel=1e-12)


def test_stone_agrees_with_erfa_refco_above_20_deg():
    # Stone and ERFA's A tan z + B tan^3 z are independent models; for the Waco weather they
    # differ by at most 0.08" from 20 to 90 deg altitude (measured), well inside 1".
    zenith_deg = np.linspace(0.0, 70.0, 141)
    difference = stone(zenith_deg) - erfa_refraction_arcsec(zenith_deg, **WACO)
    assert np.max(np.abs(difference)) < 0.15


def test_refraction_range_of_the_observed_stars():
    # 6.3: refraction of the six stars lies between 30" (Eta Cep, 59.8 deg) and 130" (HIP 47193, 22.9 deg).
    assert 30.0 < stone(90.0 - 59.8) < 33.0
    assert 127.0 < stone(90.0 - 22.9) < 130.0


def test_temperature_sensitivity_at_20_deg():
    # 4.3.2: at 20 deg altitude a 3 C change moves refraction by 1.5". Measured: -1.61" for
    # +3 C with humidity 74 %, -1.52" for dry air (Fig. 4.10 is for dry air).
    assert stone(70.0, temperature_c=25.8) - stone(70.0) == pytest.approx(-1.6, abs=0.15)
    assert (stone(70.0, temperature_c=25.8, relative_humidity=0.0)
            - stone(70.0, relative_humidity=0.0)) == pytest.approx(-1.5, abs=0.1)


def test_pressure_sensitivity_at_20_deg():
    # 4.3.2: "an unusual high pressure fluctuation of 30 mbar affects ... by 4.5 arcsec". Measured 4.50".
    assert stone(70.0, pressure_hpa=996.3 + 30.0) - stone(70.0) == pytest.approx(4.5, abs=0.1)


def test_humidity_lowers_refraction_by_less_than_1_arcsec():
    # 4.3.2 / Fig. 4.10: moist air refracts less; 74 % changes R by < 1" over 20-60 deg.
    # Measured: -0.10" at 60 deg to -0.48" at 20 deg.
    zenith_deg = np.linspace(30.0, 70.0, 41)
    change = stone(zenith_deg) - stone(zenith_deg, relative_humidity=0.0)
    assert np.all(change < 0.0)
    assert np.max(np.abs(change)) < 1.0


def test_refraction_vanishes_at_zenith_and_without_air():
    assert stone(0.0) == 0.0
    assert stone(45.0, pressure_hpa=0.0, relative_humidity=0.0) == 0.0


def test_topocentric_solution_inverts_the_observed_model():
    topocentric_deg = np.array([10.0, 40.0, 67.0, 79.9])
    refraction = stone_refraction_from_topocentric_arcsec(topocentric_deg, **WACO, **WACO_SITE)
    observed_deg = topocentric_deg - refraction / 3600.0
    np.testing.assert_allclose(observed_deg + stone(observed_deg) / 3600.0, topocentric_deg,
                               atol=1e-9 / 3600.0)


def test_apparent_altitude_is_eq_6_2():
    assert apparent_altitude_deg(31.65, 88.3) == pytest.approx(31.65 + 88.3 / 3600.0, abs=1e-12)


def test_nan_weather_is_refused():
    with pytest.raises(InvalidArgumentError, match='temperature_c contains NaN'):
        stone(45.0, temperature_c=float('nan'))


def test_humidity_in_percent_is_refused():
    with pytest.raises(InvalidArgumentError, match=r'relative_humidity must be in \[0, 1\]'):
        air_refractivity(22.8, 996.3, 74.0, 0.55)


def test_out_of_range_pressure_and_wavelength_are_refused():
    with pytest.raises(InvalidArgumentError, match='pressure_hpa must be in'):
        erfa_refraction_arcsec(45.0, **{**WACO, 'pressure_hpa': -5.0})
    with pytest.raises(InvalidArgumentError, match='wavelength_um must be in'):
        stone(45.0, wavelength_um=0.1)


def test_zenith_distance_beyond_the_series_range_is_refused():
    with pytest.raises(InvalidArgumentError, match='observed_zenith_distance_deg must be in'):
        stone(85.0)
    with pytest.raises(InvalidArgumentError, match='topocentric_zenith_distance_deg must be in'):
        stone_refraction_from_topocentric_arcsec(-1.0, **WACO, **WACO_SITE)
