"""`sofia demo`: the science core recomputes the thesis' own tables, side by side.

Each row prints the thesis value, ours, the deviation and the tolerance the test
suite holds it to; a row outside its tolerance says FAIL.
"""

from __future__ import annotations

import datetime as dt
import warnings
from dataclasses import dataclass

import numpy as np

from sofia_ros import flexure
from sofia_ros.earth_rate import best_fit_heading_deg, earth_rate_tarf_deg_per_h

__all__ = ['run_demo']

CDT = dt.timezone(dt.timedelta(hours=-5))


@dataclass(frozen=True)
class Row:
    """One thesis number against its recomputation."""

    quantity: str
    thesis: float
    computed: float
    tolerance: float
    unit: str

    def line(self):
        deviation = self.computed - self.thesis
        status = 'ok' if abs(deviation) <= self.tolerance else 'FAIL'
        return (f'  {self.quantity:<44s} {self.thesis:>12.4f} {self.computed:>12.4f} '
                f'{deviation:>+10.4f} {self.tolerance:>8.4f} {self.unit:<9s} {status}')


def _section(out, title, rows):
    out.write(f'\n{title}\n')
    out.write(f'  {"quantity":<44s} {"thesis":>12s} {"computed":>12s} {"deviation":>10s} {"toler.":>8s} unit\n')
    for row in rows:
        out.write(row.line() + '\n')


def _earth_rate_rows():
    latitude_deg, elevation_deg = 34.9368, 40.1077
    rows = []
    for heading_deg, expected in ((324.0, (9.9755, -11.2571, 0.0059)), (327.2, (10.3645, -10.8911, 0.4404))):
        rates = earth_rate_tarf_deg_per_h(latitude_deg, heading_deg, elevation_deg)
        for axis, thesis, ours in zip(('EL', 'XEL', 'LOS'), expected, rates):
            rows.append(Row(f'{axis} Earth rate, heading {heading_deg:g} deg', thesis, float(ours), 0.0005, 'deg/h'))
    heading = best_fit_heading_deg([10.3002, -10.7287, 0.3495], latitude_deg, elevation_deg)
    rows.append(Row('least-squares heading (printed 327.7, a slip)', 327.2, heading, 0.05, 'deg'))
    return rows


def _flexure_rows():
    load = flexure.gravity_load_tarf
    rows = []
    for elevation_deg in (20.0, 40.0, 60.0):
        phi_w = flexure.focal_plane_image_motion(load(elevation_deg))[2]
        closed = 69.902 * np.sin(np.radians(elevation_deg)) - 0.061 * np.cos(np.radians(elevation_deg))
        rows.append(Row(f'phi_W at {elevation_deg:g} deg (3.23 vs 3.25)', float(closed), float(phi_w), 1e-9, 'arcsec'))
    ffi = flexure.differential_imager_rotation_arcsec('ffi', load(60.0), load(23.0))
    rows.append(Row('FFI XEL differential flexure 23->60 deg (6.2)', 9.0, float(ffi[1]), 0.5, 'arcsec'))
    return rows


def _alignment_rows():
    from sofia_ros.calibration.accuracy import sigma_beta_from_length_rad, sigma_r_rad, standard_error_of_mean
    from sofia_ros.calibration.published import EQ_6_1
    from sofia_ros.frames import rotation_angles_from_dcm
    from sofia_ros.units import ARCSEC_PER_RAD, RAD_PER_ARCSEC, RAD_PER_DEG

    sigma_c_rad = 0.327 * RAD_PER_ARCSEC  # 1 HIPO pixel
    rows = []
    # Table 6.5 is headed gamma = 4 deg, but its sigma_R follows from eq. 3.32 with 5 deg.
    for n, sigma_r_arcsec, sigma_beta_arcmin in ((1, 5.3, 5.5), (18, 1.2, 1.3)):
        sigma_r = standard_error_of_mean(sigma_r_rad(sigma_c_rad, 5.0 * RAD_PER_DEG), n) * ARCSEC_PER_RAD
        sigma_beta = standard_error_of_mean(sigma_beta_from_length_rad(sigma_c_rad, 4.8 / 60 * RAD_PER_DEG), n)
        rows.append(Row(f'sigma_R, n = {n}, 5 deg LOS rotation', sigma_r_arcsec, sigma_r, 0.05, 'arcsec'))
        rows.append(Row(f'sigma_beta, n = {n}, L = 4.8 arcmin', sigma_beta_arcmin,
                        sigma_beta * ARCSEC_PER_RAD / 60.0, 0.05, 'arcmin'))
    # Eq. 6.1 as printed is orthonormal to 9e-6 (its last digits): the re-orthonormalization's warning is about the
    # thesis' rounding, said on every demo run, not about anything the user gave.
    with warnings.catch_warnings():
        warnings.filterwarnings('ignore', message='.*re-orthonormalized', category=UserWarning)
        angles_arcsec = rotation_angles_from_dcm(EQ_6_1) * ARCSEC_PER_RAD
    for axis, design_arcsec, ours in zip(('EL', 'XEL', 'LOS'), (1030.0, 730.0, 3590.0), angles_arcsec):
        rows.append(Row(f'eq. 6.1 rotation about {axis} (docs/conventions.md)', design_arcsec, float(ours), 10.0, 'arcsec'))
    return rows


def _star_rows():
    from sofia_ros.sky import WACO_2004_SITE, WACO_2004_WEATHER, astrometric_observed_place, place_distance_arcsec

    # Table D.3 row 1 and row 14: (star, altitude deg, refraction arcsec), pair distance after refraction.
    cases = (
        (dt.datetime(2004, 9, 2, 23, 22, 16, tzinfo=CDT), ('Eta Cep', 59.77, 31.8), ('Polaris', 31.65, 88.3), 101196.3),
        (dt.datetime(2004, 9, 3, 0, 44, 26, tzinfo=CDT), ('Xi Cep', 56.97, 35.5), ('HIP 47193', 23.00, 127.8), 122310.2),
    )
    rows = []
    for utc, first, second, distance_arcsec in cases:
        places = []
        for name, altitude_deg, refraction_arcsec in (first, second):
            place = astrometric_observed_place(name, WACO_2004_SITE, utc, WACO_2004_WEATHER)
            places.append(place)
            rows.append(Row(f'{name} altitude {utc:%H:%M} CDT', altitude_deg, place.altitude_deg, 0.05, 'deg'))
            rows.append(Row(f'{name} refraction (Stone)', refraction_arcsec, place.refraction_arcsec, 0.5, 'arcsec'))
        rows.append(Row(f'{first[0]} - {second[0]} refracted distance', distance_arcsec,
                        place_distance_arcsec(*places), 5.0, 'arcsec'))
    return rows


def run_demo(out):
    """Print the science core against the thesis tables; return 0, or 1 if a row is outside tolerance."""
    sections = (
        ('Table 5.7 - Earth rate sensed by the gyros at Edwards, CD 40.1077 deg (eqs. 4.1-4.3)', _earth_rate_rows()),
        ('Tables 3.2/3.3 - gravity flexure (eqs. 3.21-3.29) and section 6.2', _flexure_rows()),
        ('Table 6.5 and eq. 6.1 - alignment accuracy and the 2004 gyro alignment', _alignment_rows()),
        ('Table D.3 - Waco 2004-09-02/03: Hipparcos through ERFA, Stone refraction', _star_rows()),
    )
    failures = 0
    for title, rows in sections:
        _section(out, title, rows)
        failures += sum(abs(row.computed - row.thesis) > row.tolerance for row in rows)
    out.write(f'\n{failures} row(s) outside tolerance\n')
    return 1 if failures else 0
