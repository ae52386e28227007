"""Observed places of Hipparcos stars for a site, UTC time and weather, through ERFA (thesis 6.3).

Two places are offered. ``observed_place`` is the physically complete one: the apparent place
(proper motion, parallax, light deflection, annual aberration, precession-nutation) put on the
local horizon with ERFA's CIO chain, plus refraction. ``astrometric_observed_place`` leaves out
light deflection and aberration, as the thesis did: it placed SIMBAD mean positions of equinox
2004.7 (Table 6.6) with eqs. C.1-C.3. Rotations (precession, nutation, Earth rotation) leave
star-pair distances unchanged, but annual aberration (up to 20.5") does not: between the stars
of Table D.3 the apparent place changes the distances by up to 4.3", while the astrometric
place reproduces both distance columns to 0.1". Table D.3 therefore used the astrometric place.

Azimuth is counted from North through East (App. C.4.2), altitude above the horizon. Times
are timezone-aware datetimes (Table D.3 is in CDT = UTC - 5 h). UT1 - UTC (``dut1_s``)
defaults to 0: |DUT1| < 0.9 s turns azimuths by less than 14" and leaves pair distances alone.
Polar motion is neglected (< 0.5").
"""

from __future__ import annotations

import datetime as dt
import warnings
from dataclasses import dataclass

import erfa
import numpy as np

from sofia_ros.errors import BelowHorizonError, InvalidArgumentError
from sofia_ros.mount import unit_vector_hrf
from sofia_ros.sky.catalogue import HIPPARCOS_EPOCH_JYEAR, StarEntry, find_star, hipparcos_columns
from sofia_ros.sky.refraction import (
    MAX_ZENITH_DISTANCE_DEG,
    apparent_altitude_deg,
    checked_weather,
    stone_refraction_from_topocentric_arcsec,
)
from sofia_ros.units import ARCSEC_PER_RAD, DEG_PER_RAD, RAD_PER_ARCSEC, RAD_PER_DEG
from sofia_ros.validate import finite_scalar

__all__ = [
    'TELESCOPE_MIN_ELEVATION_DEG',
    'REFRACTION_MODELS',
    'Site',
    'Weather',
    'ObservedPlace',
    'VisibleStar',
    'WACO_2004_SITE',
    'WACO_2004_WEATHER',
    'EDWARDS_2007_SITE',
    'observed_place',
    'astrometric_observed_place',
    'mean_place_of_date_deg',
    'visible_stars',
    'observed_directions_hrf',
]

#: Lowest telescope elevation at which stars are observed.
TELESCOPE_MIN_ELEVATION_DEG = 20.0
# The complete apparent place, or the aberration-free one Table D.3 was made with.
_PLACES = ('apparent', 'astrometric')
#: 'stone': Stone's model (4.33-4.35), the thesis' choice; 'erfa': ERFA's own refracted place.
REFRACTION_MODELS = ('stone', 'erfa')

# Refraction stays below 0.6 deg even at the horizon: a star more than this below a limit
# cannot reach it, and is refused before a refraction model is evaluated.
_MAX_REFRACTION_DEG = 1.0
_J2000_JYEAR = 2000.0


@dataclass(frozen=True)
class Site:
    """Observer on the WGS84 ellipsoid; longitude positive East."""

    latitude_deg: float
    longitude_deg: float
    height_m: float

    def __post_init__(self):
        checks = (('latitude_deg', -90.0, 90.0), ('longitude_deg', -360.0, 360.0),
                  ('height_m', -500.0, 20000.0))
        for name, low, high in checks:
            value = finite_scalar(name, getattr(self, name))
            if not low <= value <= high:
                raise InvalidArgumentError(f'{name} must be in [{low:g}, {high:g}], got {value:g}')
            object.__setattr__(self, name, value)


@dataclass(frozen=True)
class Weather:
    """Surface conditions for refraction; relative_humidity is a fraction (0.74, not 74)."""

    temperature_c: float
    pressure_hpa: float
    relative_humidity: float
    wavelength_um: float

    def __post_init__(self):
        values = checked_weather(self.temperature_c, self.pressure_hpa, self.relative_humidity,
                                 self.wavelength_um)
        for name, value in zip(('temperature_c', 'pressure_hpa', 'relative_humidity',
                                'wavelength_um'), values):
            object.__setattr__(self, name, value)


@dataclass(frozen=True)
class ObservedPlace:
    """A star on the local horizon: catalogue (unrefracted) altitude, refraction, eq. 6.2 altitude."""

    hip: int
    utc: dt.datetime
    altitude_deg: float
    azimuth_deg: float
    refraction_arcsec: float
    apparent_altitude_deg: float
    refraction_model: str
    place: str


@dataclass(frozen=True)
class VisibleStar:
    """A catalogue star together with where it is seen."""

    star: StarEntry
    observed: ObservedPlace


#: TSTC Waco airport, TX, site of the 2004 on-sky tests (docs/conventions.md, Data).
WACO_2004_SITE = Site(latitude_deg=31.638, longitude_deg=-97.074, height_m=144.0)
#: Waco Regional Airport, 2004-09-02 24:00 CDT (NCDC, thesis 6.3), at 550 nm.
WACO_2004_WEATHER = Weather(temperature_c=22.8, pressure_hpa=996.3, relative_humidity=0.74,
                            wavelength_um=0.55)
#: Edwards AFB hangar, 2007 gyro stability tests: N 34 deg 56.21', W 117 deg 53.35', 697 m (Table 5.3).
EDWARDS_2007_SITE = Site(latitude_deg=34.9368, longitude_deg=-117.889, height_m=697.0)


def _utc_julian_dates(utc):
    """Return (UTC two-part JD, TT two-part JD) of a timezone-aware datetime."""
    if not isinstance(utc, dt.datetime) or utc.tzinfo is None or utc.utcoffset() is None:
        raise InvalidArgumentError(
            f'utc must be a timezone-aware datetime (e.g. tzinfo=datetime.timezone.utc), got {utc!r}'
        )
    utc = utc.astimezone(dt.timezone.utc)
    seconds = utc.second + utc.microsecond * 1e-6
    utc1, utc2 = erfa.dtf2d('UTC', utc.year, utc.month, utc.day, utc.hour, utc.minute, seconds)
    tt1, tt2 = erfa.taitt(*erfa.utctai(utc1, utc2))
    return (utc1, utc2), (tt1, tt2)


def _star_data_at(columns, epoch_jd):
    """Propagate catalogue rows from J1991.25 to ``epoch_jd`` (eraPmsafe); ERFA units."""
    pm_ra_rad = columns['pm_ra_mas_per_yr'] * 1e-3 * RAD_PER_ARCSEC / np.cos(columns['dec_rad'])
    pm_dec_rad = columns['pm_dec_mas_per_yr'] * 1e-3 * RAD_PER_ARCSEC
    # Hipparcos has non-positive parallaxes for distant stars: take them as infinitely far.
    parallax_arcsec = np.clip(columns['parallax_mas'], 0.0, None) * 1e-3
    with warnings.catch_warnings():
        # ERFA warns that it caps the distance of zero-parallax stars; that is intended here.
        warnings.simplefilter('ignore', erfa.ErfaWarning)
        ra, dec, pm_ra, pm_dec, parallax, radial = erfa.pmsafe(
            columns['ra_rad'], columns['dec_rad'], pm_ra_rad, pm_dec_rad, parallax_arcsec, 0.0,
            *erfa.epj2jd(HIPPARCOS_EPOCH_JYEAR), *epoch_jd)
    return ra, dec, pm_ra, pm_dec, parallax, radial


def _cirs_place_rad(columns, place, tt):
    """CIRS RA/Dec of catalogue rows: apparent (eraAtci13) or astrometric (eraAtcc13 + NPB)."""
    j2000_data = _star_data_at(columns, erfa.epj2jd(_J2000_JYEAR))
    # eraAtci13 and eraAtcc13 are eraApci13 (the star-independent part, with the nutation series)
    # followed by eraAtciq / eraAtccq; the first once for every star gives the same bits at a
    # fraction of the cost for many stars.
    astrom, _ = erfa.apci13(*tt)
    if place == 'apparent':
        return erfa.atciq(*j2000_data, astrom)
    ra, dec = erfa.atccq(*j2000_data, astrom)
    # Bias-precession-nutation only (GCRS -> CIRS rotation): no aberration, no light deflection.
    direction = np.einsum('ij,...j->...i', erfa.c2i06a(*tt), erfa.s2c(ra, dec))
    return erfa.c2s(direction)


def _horizontal_places(columns, site, utc, weather, refraction_model, place, dut1_s):
    """Vectorized core: unrefracted altitude, azimuth (deg) and refraction (arcsec, NaN if unknown)."""
    if refraction_model not in REFRACTION_MODELS:
        raise InvalidArgumentError(
            f'refraction_model must be one of {REFRACTION_MODELS}, got {refraction_model!r}'
        )
    if not isinstance(site, Site) or not isinstance(weather, Weather):
        raise InvalidArgumentError(
            f'site and weather must be Site and Weather, got {type(site).__name__} and '
            f'{type(weather).__name__}'
        )
    utc_jd, tt = _utc_julian_dates(utc)
    ra, dec = _cirs_place_rad(columns, place, tt)
    observer = (*utc_jd, finite_scalar('dut1_s', dut1_s), site.longitude_deg * RAD_PER_DEG,
                site.latitude_deg * RAD_PER_DEG, site.height_m, 0.0, 0.0)
    # Zero pressure switches ERFA's refraction off: the topocentric (catalogue) place. eraAtio13
    # is eraApio13 (star-independent) followed by eraAtioq: the first once for every star.
    azimuth_rad, zenith_rad = erfa.atioq(ra, dec, erfa.apio13(*observer, 0.0, 0.0, 0.0, 1.0))[:2]
    zenith_deg = np.atleast_1d(zenith_rad * DEG_PER_RAD)
    refraction_arcsec = np.full(zenith_deg.shape, np.nan)
    if refraction_model == 'erfa':
        refracted_rad = erfa.atioq(ra, dec, erfa.apio13(*observer, weather.pressure_hpa, weather.temperature_c,
                                                        weather.relative_humidity, weather.wavelength_um))[1]
        refraction_arcsec = np.atleast_1d((zenith_rad - refracted_rad) * ARCSEC_PER_RAD)
    else:
        valid = zenith_deg <= MAX_ZENITH_DISTANCE_DEG
        refraction_arcsec[valid] = stone_refraction_from_topocentric_arcsec(
            zenith_deg[valid], temperature_c=weather.temperature_c,
            pressure_hpa=weather.pressure_hpa, relative_humidity=weather.relative_humidity,
            wavelength_um=weather.wavelength_um, latitude_deg=site.latitude_deg,
            height_m=site.height_m)
    azimuth_deg = np.atleast_1d(np.mod(azimuth_rad * DEG_PER_RAD, 360.0))
    return 90.0 - zenith_deg, azimuth_deg, refraction_arcsec


def _star_columns(stars):
    """Column dict (as _star_data_at wants it) of a sequence of StarEntry."""
    keys = ('ra_rad', 'dec_rad', 'pm_ra_mas_per_yr', 'pm_dec_mas_per_yr', 'parallax_mas')
    return {key: np.array([getattr(star, key) for star in stars]) for key in keys}


def _place_of_one_star(star, site, utc, weather, refraction_model, min_altitude_deg, place,
                       dut1_s):
    """Place one star and enforce the horizon and the elevation limit."""
    star = find_star(star)
    min_altitude_deg = finite_scalar('min_altitude_deg', min_altitude_deg)
    altitude, azimuth, refraction = (
        float(values[0]) for values in _horizontal_places(
            _star_columns([star]), site, utc, weather, refraction_model, place, dut1_s))
    label = star.name or f'HIP {star.hip}'
    if altitude < 0.0:
        raise BelowHorizonError(f'{label} is below the horizon (altitude {altitude:.2f} deg) at {utc}')
    if altitude < min_altitude_deg - _MAX_REFRACTION_DEG or (
            np.isfinite(refraction) and altitude + refraction / 3600.0 < min_altitude_deg):
        raise BelowHorizonError(
            f'{label} is at {altitude:.2f} deg altitude at {utc}, below the limit of '
            f'{min_altitude_deg:g} deg'
        )
    if not np.isfinite(refraction):
        raise InvalidArgumentError(
            f'{label} is at {altitude:.2f} deg altitude, below the '
            f'{90.0 - MAX_ZENITH_DISTANCE_DEG:g} deg where Stone\'s model holds; '
            'use refraction_model="erfa"'
        )
    return ObservedPlace(hip=star.hip, utc=utc, altitude_deg=altitude, azimuth_deg=azimuth,
                         refraction_arcsec=refraction,
                         apparent_altitude_deg=float(apparent_altitude_deg(altitude, refraction)),
                         refraction_model=refraction_model, place=place)


def observed_place(star, site, utc, weather, *, refraction_model='stone', min_altitude_deg=0.0,
                   dut1_s=0.0):
    """Apparent place (eraAtci13) on the horizon (eraAtio13) plus refraction (6.2, App. C.4.2)."""
    return _place_of_one_star(star, site, utc, weather, refraction_model, min_altitude_deg,
                              'apparent', dut1_s)


def astrometric_observed_place(star, site, utc, weather, *, refraction_model='stone',
                               min_altitude_deg=0.0, dut1_s=0.0):
    """Aberration-free catalogue place on the horizon plus refraction, as Table D.3 was made."""
    return _place_of_one_star(star, site, utc, weather, refraction_model, min_altitude_deg,
                              'astrometric', dut1_s)


def mean_place_of_date_deg(star, epoch_jyear):
    """RA, Dec (deg) of the mean place of epoch and equinox ``epoch_jyear`` (Table 6.6)."""
    star = find_star(star)
    epoch_jd = erfa.epj2jd(finite_scalar('epoch_jyear', epoch_jyear))
    ra, dec = _star_data_at(_star_columns([star]), epoch_jd)[:2]
    # Frame bias and precession (IAU 2006) only: a mean place has neither nutation nor aberration.
    direction = erfa.pmat06(*epoch_jd) @ erfa.s2c(ra[0], dec[0])
    ra, dec = erfa.c2s(direction)
    return float(np.mod(ra * DEG_PER_RAD, 360.0)), float(dec * DEG_PER_RAD)


def visible_stars(site, utc, weather, *, max_hp_magnitude=6.0,
                  min_altitude_deg=TELESCOPE_MIN_ELEVATION_DEG, refraction_model='stone',
                  dut1_s=0.0):
    """Catalogue stars brighter than max_hp_magnitude (Hp) seen above min_altitude_deg, brightest first."""
    max_hp_magnitude = finite_scalar('max_hp_magnitude', max_hp_magnitude)
    min_altitude_deg = finite_scalar('min_altitude_deg', min_altitude_deg)
    lowest_stone_deg = 90.0 - MAX_ZENITH_DISTANCE_DEG + _MAX_REFRACTION_DEG
    if refraction_model == 'stone' and min_altitude_deg < lowest_stone_deg:
        raise InvalidArgumentError(
            f'min_altitude_deg must be >= {lowest_stone_deg:g} deg with Stone\'s model; '
            'use refraction_model="erfa" lower down'
        )
    catalogue = hipparcos_columns()
    rows = np.flatnonzero(catalogue.hp_magnitude <= max_hp_magnitude)
    rows = rows[np.argsort(catalogue.hp_magnitude[rows], kind='stable')]
    columns = {key: getattr(catalogue, key)[rows] for key in
               ('ra_rad', 'dec_rad', 'pm_ra_mas_per_yr', 'pm_dec_mas_per_yr', 'parallax_mas')}
    altitude, azimuth, refraction = _horizontal_places(columns, site, utc, weather,
                                                       refraction_model, 'apparent', dut1_s)
    # Stars too low for Stone's model have NaN refraction; they are below the limit anyway.
    apparent = altitude + refraction / 3600.0
    seen = np.flatnonzero(np.nan_to_num(apparent, nan=-90.0) >= min_altitude_deg)
    return tuple(
        VisibleStar(
            star=catalogue.entry(rows[i]),
            observed=ObservedPlace(hip=int(catalogue.hip[rows[i]]), utc=utc,
                                   altitude_deg=float(altitude[i]), azimuth_deg=float(azimuth[i]),
                                   refraction_arcsec=float(refraction[i]),
                                   apparent_altitude_deg=float(apparent[i]),
                                   refraction_model=refraction_model, place='apparent'),
        )
        for i in seen
    )


def observed_directions_hrf(stars, site, utc, weather=None, *, place='apparent', dut1_s=0.0):
    """HRF unit vectors (N, W, zenith) of many stars, raised by Stone's refraction if weather is given (6.2, C.4.2)."""
    if place not in _PLACES:
        raise InvalidArgumentError(f'place must be one of {_PLACES}, got {place!r}')
    if weather is not None and not isinstance(weather, Weather):
        raise InvalidArgumentError(f'weather must be a Weather or None, got {type(weather).__name__}')
    entries = [find_star(star) for star in stars]
    # _horizontal_places always evaluates Stone's model; without weather that result is unused.
    altitude_deg, azimuth_deg, refraction_arcsec = _horizontal_places(
        _star_columns(entries), site, utc, weather or WACO_2004_WEATHER, 'stone', place, dut1_s)
    if weather is None:
        return unit_vector_hrf(altitude_deg, azimuth_deg)
    too_low = [entries[i].name or f'HIP {entries[i].hip}'
               for i in np.flatnonzero(np.isnan(refraction_arcsec))]
    if too_low:
        raise InvalidArgumentError(
            f'{", ".join(too_low)} below {90.0 - MAX_ZENITH_DISTANCE_DEG:g} deg altitude at {utc}, '
            "where Stone's model does not hold; place them without weather"
        )
    return unit_vector_hrf(apparent_altitude_deg(altitude_deg, refraction_arcsec), azimuth_deg)
