"""Atmospheric refraction: Stone's spherical model (thesis 4.3.2) and ERFA's A tan z + B tan^3 z.

Stone's model (R. C. Stone, PASP 108, 1051, 1996) is the one the thesis selected (eqs.
4.33-4.35). The refractive index n0 - 1 that drives it is computed as Stone does: the dry-air
and water-vapour refractivities of Owens (1967, Appl. Opt. 6, 51) at the observing
wavelength, with Stone's saturation vapour pressure for the humidity and his kappa = g0/g.

Stone's z is the *observed* (refracted) zenith distance, as in the refraction integral. From a
catalogue (topocentric, in vacuo) zenith distance the observed one is found by iterating
z_obs = z_top - R(z_obs). That is also what reproduces the refraction column of Table D.3 best:
within 0.09" against 0.22" for R evaluated at the topocentric zenith distance (both with the
site offset the table implies, see test_sky_places).
"""

from __future__ import annotations

import erfa
import numpy as np

from sofia_ros.errors import InvalidArgumentError
from sofia_ros.units import ARCSEC_PER_RAD, RAD_PER_DEG
from sofia_ros.validate import finite_array, finite_scalar

__all__ = [
    'MAX_ZENITH_DISTANCE_DEG',
    'checked_weather',
    'saturation_vapour_pressure_hpa',
    'water_vapour_pressure_hpa',
    'air_refractivity',
    'gravity_ratio',
    'scale_height_ratio',
    'stone_refraction_arcsec',
    'stone_refraction_from_topocentric_arcsec',
    'erfa_refraction_constants_rad',
    'erfa_refraction_arcsec',
    'apparent_altitude_deg',
]

#: Largest zenith distance the tan z / tan^3 z series (Stone's and ERFA's) accept. The series
#: diverges towards the horizon: Stone quotes 10 mas accuracy to z = 65 deg and the thesis
#: (Table 4.2) uses it above 15 deg altitude; beyond 80 deg tan^3 z is no longer a correction.
MAX_ZENITH_DISTANCE_DEG = 80.0

_ZERO_CELSIUS_K = 273.15
# Weather ranges accepted: Earth-surface and airborne (SOFIA flies at ~13.7 km) conditions;
# Owens' dispersion formula has poles at 0.09 and 0.16 um and is meant for the optical/IR.
_TEMPERATURE_RANGE_C = (-90.0, 60.0)
_PRESSURE_RANGE_HPA = (0.0, 1200.0)
_HUMIDITY_RANGE = (0.0, 1.0)
_WAVELENGTH_RANGE_UM = (0.3, 20.0)


def _in_range(name, value, bounds, unit):
    """Return ``value`` as a finite float inside ``bounds``; raise InvalidArgumentError otherwise."""
    number = finite_scalar(name, value)
    low, high = bounds
    if not low <= number <= high:
        raise InvalidArgumentError(f'{name} must be in [{low:g}, {high:g}] {unit}, got {number:g}')
    return number


def checked_weather(temperature_c, pressure_hpa, relative_humidity, wavelength_um):
    """Return the four weather inputs as floats; raise InvalidArgumentError if NaN or out of range."""
    return (
        _in_range('temperature_c', temperature_c, _TEMPERATURE_RANGE_C, 'deg C'),
        _in_range('pressure_hpa', pressure_hpa, _PRESSURE_RANGE_HPA, 'hPa'),
        _in_range('relative_humidity', relative_humidity, _HUMIDITY_RANGE, '(fraction, not %)'),
        _in_range('wavelength_um', wavelength_um, _WAVELENGTH_RANGE_UM, 'um'),
    )


def saturation_vapour_pressure_hpa(temperature_c):
    """Saturation water-vapour pressure over water as Stone (1996) gives it, in hPa."""
    temperature_k = finite_array('temperature_c', temperature_c) + _ZERO_CELSIUS_K
    # Stone's expression is in Pa; / 100 gives hPa (= millibar, the unit of Owens' formulas).
    pascal = np.exp(77.3450 + 0.0057 * temperature_k - 7235.0 / temperature_k) / temperature_k**8.2
    return pascal / 100.0


def water_vapour_pressure_hpa(temperature_c, relative_humidity):
    """Partial pressure of water vapour at a relative humidity (fraction 0-1), in hPa."""
    return relative_humidity * saturation_vapour_pressure_hpa(temperature_c)


def air_refractivity(temperature_c, pressure_hpa, relative_humidity, wavelength_um):
    """Refractivity n0 - 1 of moist air at the observer (Owens 1967, as used by Stone 1996)."""
    temperature_c, pressure_hpa, relative_humidity, wavelength_um = checked_weather(
        temperature_c, pressure_hpa, relative_humidity, wavelength_um
    )
    temperature_k = temperature_c + _ZERO_CELSIUS_K
    water_hpa = water_vapour_pressure_hpa(temperature_c, relative_humidity)
    # Water vapour displaces dry air: the dry-air partial pressure is the remainder.
    dry_hpa = max(pressure_hpa - water_hpa, 0.0)
    # Owens' density factors: ideal-gas P/T times his compressibility corrections.
    dry_density = (dry_hpa / temperature_k) * (
        1.0 + dry_hpa * (57.90e-8 - 9.3250e-4 / temperature_k + 0.25844 / temperature_k**2)
    )
    water_density = (water_hpa / temperature_k) * (
        1.0
        + water_hpa
        * (1.0 + 3.7e-4 * water_hpa)
        * (-2.37321e-3 + 2.23366 / temperature_k - 710.792 / temperature_k**2
           + 7.75141e4 / temperature_k**3)
    )
    sigma2 = 1.0 / wavelength_um**2  # squared vacuum wavenumber, um^-2
    dry_dispersion = 2371.34 + 683939.7 / (130.0 - sigma2) + 4547.3 / (38.9 - sigma2)
    water_dispersion = 6487.31 + 58.058 * sigma2 - 0.71150 * sigma2**2 + 0.08851 * sigma2**3
    return 1.0e-8 * (dry_dispersion * dry_density + water_dispersion * water_density)


def gravity_ratio(latitude_deg, height_m):
    """Stone's kappa = g0/g, local over equatorial sea-level gravity (eq. 4.34)."""
    latitude_rad = finite_scalar('latitude_deg', latitude_deg) * RAD_PER_DEG
    height_m = finite_scalar('height_m', height_m)
    return (
        1.0
        + 0.005302 * np.sin(latitude_rad) ** 2
        - 0.00000583 * np.sin(2.0 * latitude_rad) ** 2
        - 0.000000315 * height_m
    )


def scale_height_ratio(temperature_c):
    """Stone's beta, atmospheric scale height over Earth radius (eq. 4.35)."""
    return 0.001254 * (_ZERO_CELSIUS_K + finite_scalar('temperature_c', temperature_c)) / _ZERO_CELSIUS_K


def _checked_zenith_distance_deg(name, zenith_distance_deg):
    """Return zenith distances as a float array, refusing values outside Stone's range."""
    zenith_distance_deg = finite_array(name, zenith_distance_deg)
    if np.any((zenith_distance_deg < 0.0) | (zenith_distance_deg > MAX_ZENITH_DISTANCE_DEG)):
        raise InvalidArgumentError(
            f'{name} must be in [0, {MAX_ZENITH_DISTANCE_DEG:g}] deg: the tan z series '
            f'diverges towards the horizon (altitude < {90.0 - MAX_ZENITH_DISTANCE_DEG:g} deg)'
        )
    return zenith_distance_deg


def stone_refraction_arcsec(observed_zenith_distance_deg, *, temperature_c, pressure_hpa,
                            relative_humidity, wavelength_um, latitude_deg, height_m):
    """Stone's spherical-atmosphere refraction angle at an observed zenith distance (eqs. 4.33-4.35)."""
    tan_z = np.tan(_checked_zenith_distance_deg('observed_zenith_distance_deg',
                                                observed_zenith_distance_deg) * RAD_PER_DEG)
    refractivity = air_refractivity(temperature_c, pressure_hpa, relative_humidity, wavelength_um)
    kappa = gravity_ratio(latitude_deg, height_m)
    beta = scale_height_ratio(temperature_c)
    refraction_rad = (kappa * refractivity * (1.0 - beta) * tan_z
                      - kappa * refractivity * (beta - refractivity / 2.0) * tan_z**3)
    return refraction_rad * ARCSEC_PER_RAD


def stone_refraction_from_topocentric_arcsec(topocentric_zenith_distance_deg, *, temperature_c,
                                             pressure_hpa, relative_humidity, wavelength_um,
                                             latitude_deg, height_m):
    """Stone's refraction (4.33) for a catalogue (unrefracted) zenith distance, solving z_top = z_obs + R."""
    conditions = dict(temperature_c=temperature_c, pressure_hpa=pressure_hpa,
                      relative_humidity=relative_humidity, wavelength_um=wavelength_um,
                      latitude_deg=latitude_deg, height_m=height_m)
    topocentric_deg = _checked_zenith_distance_deg('topocentric_zenith_distance_deg',
                                                   topocentric_zenith_distance_deg)
    observed_deg = topocentric_deg
    # |dR/dz| < 0.01 above 10 deg altitude, so each pass gains two digits; 5 reach 1e-8 arcsec.
    for _ in range(5):
        refraction_arcsec = stone_refraction_arcsec(observed_deg, **conditions)
        observed_deg = topocentric_deg - refraction_arcsec / 3600.0
    return refraction_arcsec


def erfa_refraction_constants_rad(temperature_c, pressure_hpa, relative_humidity, wavelength_um):
    """ERFA's refraction constants A and B (rad) of dz = A tan z + B tan^3 z (eraRefco)."""
    temperature_c, pressure_hpa, relative_humidity, wavelength_um = checked_weather(
        temperature_c, pressure_hpa, relative_humidity, wavelength_um
    )
    refa, refb = erfa.refco(pressure_hpa, temperature_c, relative_humidity, wavelength_um)
    return float(refa), float(refb)


def erfa_refraction_arcsec(observed_zenith_distance_deg, *, temperature_c, pressure_hpa,
                           relative_humidity, wavelength_um):
    """ERFA's refraction A tan z + B tan^3 z at an observed zenith distance (eraRefco model)."""
    tan_z = np.tan(_checked_zenith_distance_deg('observed_zenith_distance_deg',
                                                observed_zenith_distance_deg) * RAD_PER_DEG)
    refa, refb = erfa_refraction_constants_rad(temperature_c, pressure_hpa, relative_humidity,
                                               wavelength_um)
    return (refa * tan_z + refb * tan_z**3) * ARCSEC_PER_RAD


def apparent_altitude_deg(altitude_deg, refraction_arcsec):
    """Altitude seen through the atmosphere, Alt_apparent = Alt + R (eq. 6.2)."""
    return finite_array('altitude_deg', altitude_deg) + finite_array('refraction_arcsec',
                                                                      refraction_arcsec) / 3600.0
