"""Truth model of one camera (FPI, FFI, WFI or HIPO): catalogue stars to centroids (2.4.3, 3.2-3.4, 6.1-6.3).

Per frame and star (each step is a function below):

1. ERFA's complete apparent place on the horizon (``observed_directions_hrf``), turned into IRF
   with A_HRF(t),IRF^T (4.1). Unrefracted, a star is inertially fixed: the IRF directions of the
   candidate stars are therefore evaluated every ``place_refresh_s`` (ERFA costs ~80 us per star)
   and held in between; measured drift < 0.003" per minute (test-pinned).
2. With ``atmospheric_refraction`` in the truth, each star is raised towards the zenith of HRF(t)
   by Stone's angle (4.33-4.35, Alt + R of eq. 6.2), looked up per frame in a table made once.
   The effect's parameters are the weather: there is no second Weather to disagree with them.
3. The given attitude A_TARF,IRF, then the camera's true mounting A_CAM,TARF.
4. Pixels through the true detector geometry (3.2-3.7), then seeing jitter (6.1).

Sign conventions, each pinned in test/test_imager_model.py:

* A mounting term turns the camera frame against TARF by theta about (EL, XEL, LOS),
  A = I - [theta x] (B.19-B.22): to that camera it looks as if the telescope turned by theta.
  A positive telescope rotation about EL moves a star on the LOS to +v, i.e. +theta/S in imager
  rows Y (eq. 3.3) and theta/S along (-sin phi, -cos phi) on HIPO (3.5-3.6); about XEL to -u, i.e.
  -theta/S in imager columns X (eq. 3.2) and theta/S along (-cos phi, +sin phi) on HIPO.
* Nominal mounting is the identity: a perfectly aligned imager's flange axes are TARF's (C.1.3),
  HIPO's frame is TARF (3.5-3.7). True mounting: A_CAM,TARF = A(rotation of field about LOS)
  A(boresight offset about EL, XEL) A(flexure).
* Flexure: ``focal_plane_flexure`` turns HIPO and the FPI (behind the telescope optics) by the
  equivalent telescope rotation (dEL, dXEL) = (-phi_V, -phi_W) of Table 3.2; ``imager_flexure``
  turns the head-ring FFI and WFI by the rotations of Table 3.3; ``fpi_internal_flexure`` turns
  the FPI by (el, xel)_arcsec_per_g times the load along -LOS in g, sin(el) (6.2). A star held on
  HIPO's flange centre then moves in the FFI by 8.96" XEL and -3.24" EL from 23 to 60 deg (6.2
  measured about 9" XEL), in the FPI by 1.10" XEL with the internal flexure (6.2: 1.1").
* Detector errors: true flange centre and phi = HIPO 2004 + ``hipo_fiducial_error`` (defaults give
  the 2008 fiducials); true imager scale = Table 2.6 scale x (1 + ppm 1e-6) (``imager_scale_error``).
* Pixels: imagers count from 0 (centre 511.5, C.1.3), HIPO from 1 to 1152 and 1030 (3.3.1); a star
  is on the chip within half a pixel beyond the outer pixel centres.
* Stamps: a frame whose shutter opens at ``elapsed_s`` shows the sky at mid-exposure, seen with the
  attitude given (the caller's mean over the exposure), and is stamped then (6.1), plus the HIPO
  clock offset (``timestamp_offset``, 6.2) for HIPO only.

Simplifications: seeing jitter is independent per star and frame and does not scale with exposure
time (the 0.3" RMS of 6.1 was measured with 0.5-5 s exposures); with refraction on, stars below
10 deg altitude (outside Stone's range) are not imaged; the magnitude limit applies to Hipparcos
Hp; distortion is ignored (3.3.1); the vignetted corners of the FPI (Table 2.6) are imaged.
"""

from __future__ import annotations

import dataclasses
import datetime as dt
import functools

import numpy as np

from sofia_ros.effects import get_effect, plugin_terms, resolve_params
from sofia_ros.effects.context import CameraContext
from sofia_ros.errors import ConfigError, InvalidArgumentError
from sofia_ros.flexure import (
    IMAGER_FLEXURE,
    focal_plane_telescope_rotation_arcsec,
    gravity_load_tarf,
    imager_rotation_arcsec,
)
from sofia_ros.frames import (
    FFI,
    FPI,
    HIPO_2004,
    WFI,
    DetectorGeometry,
    dcm_from_rotation_angles,
    pixel_to_vector,
    vector_to_pixel,
)
from sofia_ros.graph_nodes import IMAGERS
from sofia_ros.mount import altaz_from_unit_vector_hrf, hrf_from_irf_dcm, unit_vector_hrf
from sofia_ros.rotation_kernels import matrices_from_rotvecs
from sofia_ros.sky.catalogue import StarEntry, hipparcos_columns
from sofia_ros.sky.places import Site, Weather, observed_directions_hrf
from sofia_ros.sky.refraction import MAX_ZENITH_DISTANCE_DEG, stone_refraction_from_topocentric_arcsec
from sofia_ros.units import RAD_PER_ARCSEC, RAD_PER_DEG, STANDARD_GRAVITY_M_PER_S2
from sofia_ros.validate import finite_array, finite_scalar, orthonormal_dcm, positive_scalar

__all__ = [
    'CAMERAS',
    'MAGNITUDE_LIMIT_MAG',
    'Scene',
    'Centroid',
    'nominal_detector',
    'CameraErrors',
    'camera_errors',
    'flexure_rotation_arcsec',
    'camera_from_tarf_dcm',
    'flexure_dcm',
    'flexure_key',
    'mounted_dcm',
    'mounting_key',
    'shifted_centroids_px',
    'star_directions_irf',
    'refracted_directions_hrf',
    'select_candidate_stars',
    'predicted_centroid_px',
    'ImagerTruth',
]

#: The sensor model's order: the imagers, then HIPO (graph_nodes names them).
CAMERAS = (*IMAGERS, 'hipo')
#: Required sensitivity of Table 2.6 as an Hp limit; HIPO sees through the telescope like the FPI.
MAGNITUDE_LIMIT_MAG = {'wfi': 8.0, 'ffi': 13.0, 'fpi': 16.0, 'hipo': 16.0}
_NOMINAL_DETECTORS = {'hipo': HIPO_2004, 'fpi': FPI, 'ffi': FFI, 'wfi': WFI}
# Number of the first pixel: C.1.3 puts the imager origin at (0/0); HIPO counts from 1 (3.3.1).
_FIRST_PIXEL = {'hipo': 1.0, 'fpi': 0.0, 'ffi': 0.0, 'wfi': 0.0}
# 0.02 deg steps: linear interpolation of Stone's R(z) is then good to 1e-4" up to z = 80 deg.
_REFRACTION_GRID_DEG = np.linspace(0.0, MAX_ZENITH_DISTANCE_DEG, 4001)
_MIN_SIN_ALTITUDE_REFRACTED = np.cos(MAX_ZENITH_DISTANCE_DEG * RAD_PER_DEG)
# The ICRS axes as stars at infinity: placing them gives A_IRF,ICRS to ~20" (aberration).
_ICRS_AXES_AS_STARS = tuple(
    StarEntry(hip=0, ra_rad=ra, dec_rad=dec, pm_ra_mas_per_yr=0.0, pm_dec_mas_per_yr=0.0,
              parallax_mas=0.0, hp_magnitude=0.0, b_minus_v_mag=0.0)
    for ra, dec in ((0.0, 0.0), (np.pi / 2.0, 0.0), (0.0, np.pi / 2.0))
)


@dataclasses.dataclass(frozen=True)
class Scene:
    """Site, UTC of the IRF epoch (IRF = HRF then) and latitude for Earth rotation (4.1, C.1.2)."""

    site: Site
    epoch_utc: dt.datetime
    earth_latitude_deg: float | None = None

    def __post_init__(self):
        if not isinstance(self.site, Site):
            raise InvalidArgumentError(f'site must be a Site, got {type(self.site).__name__}')
        if not isinstance(self.epoch_utc, dt.datetime) or self.epoch_utc.utcoffset() is None:
            raise InvalidArgumentError(f'epoch_utc must be a timezone-aware datetime, got {self.epoch_utc!r}')
        latitude = self.site.latitude_deg if self.earth_latitude_deg is None else self.earth_latitude_deg
        object.__setattr__(self, 'earth_latitude_deg', finite_scalar('earth_latitude_deg', latitude))

    def utc_at(self, elapsed_s):
        """UTC at ``elapsed_s`` seconds after the IRF epoch."""
        return self.epoch_utc + dt.timedelta(seconds=finite_scalar('elapsed_s', elapsed_s))


@dataclasses.dataclass(frozen=True)
class Centroid:
    """One star's centroid in one frame: HIP number, pixel (X, Y), mid-exposure stamp of the camera clock."""

    hip: int
    x_px: float
    y_px: float
    stamp_s: float


def _checked_camera(camera):
    if camera not in CAMERAS:
        raise InvalidArgumentError(f'camera must be one of {CAMERAS}, got {camera!r}')
    return camera


def _params(effects, name):
    """Resolved parameters of effect ``name`` if it is in the set, else None."""
    return resolve_params(name, effects[name]) if name in effects else None


def nominal_detector(camera):
    """Detector geometry the TASCU assumes: HIPO's 2004 fiducials (3.3.1), imager scales of Table 2.6."""
    return _NOMINAL_DETECTORS[_checked_camera(camera)]


def _true_detector(camera, effects):
    """Detector geometry with hipo_fiducial_error (3.3.1 footnote) or imager_scale_error (Table 2.6)."""
    nominal = nominal_detector(camera)
    if camera == 'hipo':
        error = _params(effects, 'hipo_fiducial_error')
        if error is None:
            return nominal
        return dataclasses.replace(nominal, center_x_px=nominal.center_x_px + error['center_x_px'],
                                   center_y_px=nominal.center_y_px + error['center_y_px'],
                                   rotation_deg=nominal.rotation_deg + error['phi_deg'])
    error = _params(effects, 'imager_scale_error')
    if error is None:
        return nominal
    scale = nominal.scale_arcsec_per_px * (1.0 + error[f'{camera}_ppm'] * 1e-6)
    return dataclasses.replace(nominal, scale_arcsec_per_px=scale)


@dataclasses.dataclass(frozen=True)
class CameraErrors:
    """One camera's share of an effect set, resolved once; zero is off (3.3, 3.4.1, 6.1-6.2)."""

    camera: str
    detector: DetectorGeometry
    boresight_el_xel_arcsec: tuple = (0.0, 0.0)
    rotation_of_field_deg: float = 0.0
    focal_plane_flexure_scale: float = 0.0
    internal_flexure_el_xel_arcsec_per_g: tuple = (0.0, 0.0)
    head_ring_flexure_scale: float = 0.0
    seeing_rms_arcsec: float = 0.0
    clock_offset_s: float = 0.0
    weather: Weather | None = None
    #: HookTerms of plug-in effects that rotate the camera frame (EffectSpec.camera_rotation).
    plugins: tuple = ()
    #: HookTerms of plug-in and empirical effects that shift centroids (EffectSpec.camera_shift_px).
    shift_plugins: tuple = ()


#: Effect parameter sets _resolved_params keeps (a fit's steps of one model come back within an iteration).
_RESOLVED_ENTRIES = 512
_resolved = {}


def _resolved_params(name, params):
    """resolve_params(name, params), kept: a fit steps one number of one effect at a time, and camera_errors resolved
    every effect of the set again for each step and camera (with the weather's checks, 16 % of the fits of an
    alignment compare). Kept by the effect's spec (a plug-in registered anew is resolved anew) and the repr of what
    was given (plain YAML values: repr tells 1 from 1.0 and True); handed out as a copy, shared by no caller."""
    spec = get_effect(name)
    key = (name, id(spec), repr(params))
    kept = _resolved.get(key)
    if kept is None or kept[0] is not spec:
        if len(_resolved) >= _RESOLVED_ENTRIES:
            _resolved.clear()  # rather than an order: what a fit asks for again comes back within an iteration
        kept = _resolved[key] = (spec, resolve_params(name, params))
    return dict(kept[1])


@functools.lru_cache(maxsize=16)
def _weather(temperature_c, pressure_hpa, relative_humidity, wavelength_um):
    """The Weather of resolved refraction parameters, checked once per set (Weather checks each value)."""
    return Weather(temperature_c, pressure_hpa, relative_humidity, wavelength_um)


def camera_errors(camera, effects):
    """The errors an effect set gives one camera; unknown effects or parameters raise (docs/effects.md)."""
    camera = _checked_camera(camera)
    if not isinstance(effects, dict):
        raise ConfigError(f'effects must map effect names to parameters, got {type(effects).__name__}')
    effects = {name: _resolved_params(name, params) for name, params in effects.items()}
    values = {}
    offset, field = effects.get('imager_boresight_offset'), effects.get('imager_rotation_of_field')
    if offset is not None and camera != 'hipo':
        values['boresight_el_xel_arcsec'] = (offset[f'{camera}_el_arcsec'], offset[f'{camera}_xel_arcsec'])
    if field is not None and camera != 'hipo':
        values['rotation_of_field_deg'] = field[f'{camera}_deg']
    focal_plane, internal = effects.get('focal_plane_flexure'), effects.get('fpi_internal_flexure')
    if focal_plane is not None and camera in ('hipo', 'fpi'):
        values['focal_plane_flexure_scale'] = focal_plane['scale']
    if internal is not None and camera == 'fpi':
        values['internal_flexure_el_xel_arcsec_per_g'] = (internal['el_arcsec_per_g'],
                                                          internal['xel_arcsec_per_g'])
    head_ring = effects.get('imager_flexure')
    if head_ring is not None and camera in IMAGER_FLEXURE:
        values['head_ring_flexure_scale'] = head_ring[f'{camera}_scale']
    if 'seeing' in effects:
        values['seeing_rms_arcsec'] = effects['seeing']['rms_arcsec']
    if 'timestamp_offset' in effects and camera == 'hipo':
        values['clock_offset_s'] = effects['timestamp_offset']['offset_s']
    refraction = effects.get('atmospheric_refraction')
    if refraction is not None:
        values['weather'] = _weather(refraction['temperature_c'], refraction['pressure_hpa'],
                                     refraction['humidity'], refraction['wavelength_um'])
    return CameraErrors(camera, _true_detector(camera, effects), plugins=plugin_terms(effects, 'camera_rotation'),
                        shift_plugins=plugin_terms(effects, 'camera_shift_px'), **values)


def flexure_rotation_arcsec(errors, elevation_deg, context=None):
    """Gravity rotation (EL, XEL, LOS) ["] of a camera frame against TARF (Tables 3.2, 3.3; 6.2) and plug-ins', (..., 3).

    Plug-in rotation hooks get ``context`` (a CameraContext of the same rows), or one made from
    the elevation alone (the telescope at rest) when none is given.
    """
    load = gravity_load_tarf(elevation_deg)
    los_load_g = -load[..., 2:] / STANDARD_GRAVITY_M_PER_S2
    # Rotations below 2' add as vectors: the second-order error is below 1e-3".
    rotation = np.zeros(load.shape)
    rotation[..., :2] = (errors.focal_plane_flexure_scale * focal_plane_telescope_rotation_arcsec(load)
                         + los_load_g * np.asarray(errors.internal_flexure_el_xel_arcsec_per_g))
    if errors.head_ring_flexure_scale:
        rotation += errors.head_ring_flexure_scale * imager_rotation_arcsec(errors.camera, load)
    if errors.plugins:
        if context is None:
            context = CameraContext.at_rest(errors.camera, elevation_deg)
        for term in errors.plugins:
            rotation += term(context).reshape(rotation.shape)
    return rotation


def shifted_centroids_px(errors, pixels_px, context, hip):
    """Centroids plus the plug-in shifts (EffectSpec.camera_shift_px) at their detector positions, (N, 2)."""
    pixels = np.asarray(pixels_px, dtype=float)
    if not errors.shift_plugins or len(pixels) == 0:
        return pixels
    located = context.with_detector(pixels, hip)
    return pixels + sum(term(located) for term in errors.shift_plugins)


@functools.lru_cache(maxsize=16)
def _fixed_mounting_dcm(boresight_el_xel_arcsec, rotation_of_field_deg):
    """A(rotation of field about LOS) A(boresight offset about EL, XEL) of an imager (3.3.1, 3.3.3)."""
    boresight_rad = np.array([*boresight_el_xel_arcsec, 0.0]) * RAD_PER_ARCSEC
    dcm = (dcm_from_rotation_angles([0.0, 0.0, rotation_of_field_deg * RAD_PER_DEG])
           @ dcm_from_rotation_angles(boresight_rad))
    dcm.flags.writeable = False  # the cached matrix is shared by every caller
    return dcm


def flexure_dcm(errors, elevation_deg, context=None):
    """A(flexure) of camera_from_tarf_dcm: the gravity rotation (Tables 3.2, 3.3; 6.2) and plug-ins', (..., 3, 3)."""
    flexure_rad = flexure_rotation_arcsec(errors, elevation_deg, context) * RAD_PER_ARCSEC
    dcms = np.swapaxes(matrices_from_rotvecs(flexure_rad.reshape(-1, 3)), -1, -2)
    return dcms.reshape(*flexure_rad.shape[:-1], 3, 3)


def mounted_dcm(errors, flexure):
    """A(rotation of field) A(boresight offset) times a camera's flexure DCMs (flexure_dcm), (..., 3, 3) (3.3.1, 3.3.3).

    Without a boresight offset or a rotation of field, ``flexure`` itself: the identity's product gives back the
    same numbers bit for bit (1 x + 0 y + 0 z), at the cost of a batched product of every row.
    """
    if errors.boresight_el_xel_arcsec == (0.0, 0.0) and errors.rotation_of_field_deg == 0.0:
        return flexure
    fixed = _fixed_mounting_dcm(errors.boresight_el_xel_arcsec, errors.rotation_of_field_deg)
    return (fixed @ flexure.reshape(-1, 3, 3)).reshape(flexure.shape)


def camera_from_tarf_dcm(errors, elevation_deg, context=None):
    """True A_CAM,TARF = A(rotation of field) A(boresight offset) A(flexure) (3.3.1, 3.3.3, 3.4.1); (..., 3, 3)."""
    return mounted_dcm(errors, flexure_dcm(errors, elevation_deg, context))


#: CameraErrors fields that do not turn a camera's frame against TARF (camera_from_tarf_dcm): the detector and the
#: centroid shifts act after it, the seeing on the centroids, the clock offset and the weather on the stars' times
#: and places. A field added to CameraErrors counts for the frame until it is named here (a cache misses, never errs).
_NOT_MOUNTING_FIELDS = frozenset({'detector', 'shift_plugins', 'seeing_rms_arcsec', 'clock_offset_s', 'weather'})
#: The fields of the fixed mounting (_fixed_mounting_dcm), which flexure_dcm does not depend on.
_FIXED_MOUNTING_FIELDS = frozenset({'boresight_el_xel_arcsec', 'rotation_of_field_deg'})


def mounting_key(errors):
    """What camera_from_tarf_dcm takes from ``errors`` (besides elevation and context), as a string for a cache key."""
    return repr([(field.name, getattr(errors, field.name)) for field in dataclasses.fields(errors)
                 if field.name not in _NOT_MOUNTING_FIELDS])


def flexure_key(errors):
    """What flexure_dcm takes from ``errors`` (besides elevation and context), as a string to key a cache by."""
    return repr([(field.name, getattr(errors, field.name)) for field in dataclasses.fields(errors)
                 if field.name not in _NOT_MOUNTING_FIELDS | _FIXED_MOUNTING_FIELDS])


def star_directions_irf(stars, scene, elapsed_s, weather=None):
    """IRF unit vectors (N, 3) of stars: ERFA observed place in HRF(t), times A_HRF(t),IRF^T (4.1, C.4.2)."""
    directions_hrf = observed_directions_hrf(stars, scene.site, scene.utc_at(elapsed_s), weather)
    return directions_hrf @ hrf_from_irf_dcm(scene.earth_latitude_deg, elapsed_s)


@functools.lru_cache(maxsize=8)
def _refraction_table_arcsec(site, weather):
    """Stone's refraction (4.33-4.35) on the topocentric zenith-distance grid, for per-frame lookup."""
    return stone_refraction_from_topocentric_arcsec(
        _REFRACTION_GRID_DEG, temperature_c=weather.temperature_c, pressure_hpa=weather.pressure_hpa,
        relative_humidity=weather.relative_humidity, wavelength_um=weather.wavelength_um,
        latitude_deg=site.latitude_deg, height_m=site.height_m)


def refracted_directions_hrf(directions_hrf, site, weather):
    """Unrefracted HRF directions raised by Stone's refraction, Alt + R (eqs. 4.33-4.35, 6.2), tabulated."""
    altitude_deg, azimuth_deg = altaz_from_unit_vector_hrf(directions_hrf)
    zenith_deg = 90.0 - altitude_deg
    if np.any(zenith_deg > MAX_ZENITH_DISTANCE_DEG):
        raise InvalidArgumentError(f'directions_hrf must lie above {90.0 - MAX_ZENITH_DISTANCE_DEG:g} deg '
                                   "altitude, where Stone's model holds")
    refraction_arcsec = np.interp(zenith_deg, _REFRACTION_GRID_DEG, _refraction_table_arcsec(site, weather))
    return unit_vector_hrf(altitude_deg + refraction_arcsec / 3600.0, azimuth_deg)


@functools.lru_cache(maxsize=8)
def _irf_from_icrs_dcm(scene, elapsed_s):
    """A_IRF,ICRS to ~20" from the ICRS axes placed as stars (enough to select candidates).

    Kept for a few frames: the three imagers expose together and, moved together, reselect their stars
    at the same frame (ERFA's places of the three axes are most of a selection's cost).
    """
    axes_in_irf = star_directions_irf(_ICRS_AXES_AS_STARS, scene, elapsed_s)
    left, _, right = np.linalg.svd(axes_in_irf.T)
    dcm = left @ right
    dcm.flags.writeable = False  # the cached matrix is shared by every caller
    return dcm


@functools.lru_cache(maxsize=1)
def _catalogue_unit_vectors_icrs():
    """ICRS unit vectors of every Hipparcos star at J1991.25."""
    columns = hipparcos_columns()
    cos_dec = np.cos(columns.dec_rad)
    return np.stack([cos_dec * np.cos(columns.ra_rad), cos_dec * np.sin(columns.ra_rad),
                     np.sin(columns.dec_rad)], axis=-1)


def select_candidate_stars(scene, elapsed_s, axis_irf, radius_deg, max_hp_magnitude):
    """Catalogue stars with Hp <= limit within radius of an IRF direction, brightest first (Table 2.6)."""
    axis = finite_array('axis_irf', axis_irf, shape=(3,))
    axis_icrs = _irf_from_icrs_dcm(scene, elapsed_s).T @ (axis / np.linalg.norm(axis))
    columns = hipparcos_columns()
    radius_rad = positive_scalar('radius_deg', radius_deg) * RAD_PER_DEG
    bright = columns.hp_magnitude <= finite_scalar('max_hp_magnitude', max_hp_magnitude)
    rows = np.flatnonzero(bright & (_catalogue_unit_vectors_icrs() @ axis_icrs >= np.cos(radius_rad)))
    rows = rows[np.argsort(columns.hp_magnitude[rows], kind='stable')]
    return tuple(columns.entry(row) for row in rows)


def predicted_centroid_px(camera, direction_irf, tarf_from_irf, camera_from_tarf=None):
    """Error-free centroid(s) (X, Y) px: nominal detector, mounting as given or identity (3.2-3.7)."""
    camera_from_irf = orthonormal_dcm('tarf_from_irf', tarf_from_irf)
    if camera_from_tarf is not None:
        camera_from_irf = orthonormal_dcm('camera_from_tarf', camera_from_tarf) @ camera_from_irf
    direction = finite_array('direction_irf', direction_irf)
    return vector_to_pixel(direction @ camera_from_irf.T, nominal_detector(camera))


def _field_radius_deg(detector):
    """Angle from the camera axis to the farthest detector corner, one pixel beyond the chip."""
    corners = [[x, y] for x in (-1.0, detector.width_px + 1.0) for y in (-1.0, detector.height_px + 1.0)]
    return float(np.degrees(np.arccos(np.min(pixel_to_vector(corners, detector)[:, 2]))))


def _checked_elevation_deg(elevation_deg):
    elevation = finite_scalar('elevation_deg', elevation_deg)
    if not 0.0 <= elevation <= 90.0:
        raise InvalidArgumentError(f'elevation_deg must be in [0, 90], got {elevation:g}')
    return elevation


class ImagerTruth:
    """One camera's fixed truth configuration and RNG; ``centroids`` renders one frame (2.4.3, 6.1-6.3)."""

    def __init__(self, camera, effects, scene, *, exposure_s, magnitude_limit_mag=None, seed=0,
                 selection_margin_deg=0.5, place_refresh_s=60.0):
        self.errors = camera_errors(camera, effects)
        if not isinstance(scene, Scene):
            raise InvalidArgumentError(f'scene must be a Scene, got {type(scene).__name__}')
        self.scene = scene
        self.exposure_s = positive_scalar('exposure_s', exposure_s)
        if magnitude_limit_mag is None:
            magnitude_limit_mag = MAGNITUDE_LIMIT_MAG[camera]
        self.magnitude_limit_mag = finite_scalar('magnitude_limit_mag', magnitude_limit_mag)
        self._rng = np.random.default_rng(seed)
        self._selection_margin_deg = positive_scalar('selection_margin_deg', selection_margin_deg)
        self._place_refresh_s = positive_scalar('place_refresh_s', place_refresh_s)
        detector = self.errors.detector
        self._field_radius_deg = _field_radius_deg(detector)
        self._seeing_px = self.errors.seeing_rms_arcsec / detector.scale_arcsec_per_px
        first = _FIRST_PIXEL[camera]
        self._pixel_bounds = (first - 0.5, first - 0.5 + detector.width_px, first - 0.5 + detector.height_px)
        self.candidates = ()
        self._candidate_hip = np.empty(0, dtype=np.int64)
        self._selection_axis_irf = None
        self._directions_irf = np.empty((0, 3))
        self._places_elapsed_s = None
        self._mounting_at = (None, None)  # (elevation deg, camera_from_tarf_dcm there) without hooks

    def centroids(self, elapsed_s, tarf_from_irf, elevation_deg, *, temperature_c=np.nan,
                  specific_force_tarf_m_per_s2=None, los_angle_deg=0.0):
        """Centroids of every star on the chip for a frame opening at elapsed_s (3.2-3.7, 6.1).

        Temperature, specific force (TARF; at rest when not given) and fine-drive LOS angle are
        what plug-in hooks may depend on (effects.context).
        """
        start_s = finite_scalar('elapsed_s', elapsed_s)
        attitude = orthonormal_dcm('tarf_from_irf', tarf_from_irf)
        elevation = _checked_elevation_deg(elevation_deg)
        mid_s = start_s + self.exposure_s / 2.0
        context = self._hook_context(elevation, mid_s, temperature_c, specific_force_tarf_m_per_s2, los_angle_deg)
        camera_from_irf = self._camera_from_tarf(elevation, context) @ attitude
        self._update_candidates(mid_s, camera_from_irf[2])
        directions_irf, hips = self._directions_irf, self._candidate_hip
        weather = self.errors.weather
        if weather is not None:
            hrf_from_irf = hrf_from_irf_dcm(self.scene.earth_latitude_deg, mid_s)
            directions_hrf = directions_irf @ hrf_from_irf.T
            in_range = directions_hrf[:, 2] >= _MIN_SIN_ALTITUDE_REFRACTED
            refracted_hrf = refracted_directions_hrf(directions_hrf[in_range], self.scene.site, weather)
            directions_irf = refracted_hrf @ hrf_from_irf
            hips = hips[in_range]
        in_camera = directions_irf @ camera_from_irf.T
        in_front = in_camera[:, 2] > 0.0
        pixels = vector_to_pixel(in_camera[in_front], self.errors.detector)
        if self.errors.shift_plugins:
            rows = np.zeros(len(pixels), dtype=int)
            pixels = shifted_centroids_px(self.errors, pixels, context.rows(rows), hips[in_front])
        if self._seeing_px:
            pixels = pixels + self._rng.normal(0.0, self._seeing_px, size=pixels.shape)
        low, high_x, high_y = self._pixel_bounds
        x_px, y_px = pixels[:, 0], pixels[:, 1]
        on_chip = (x_px >= low) & (x_px <= high_x) & (y_px >= low) & (y_px <= high_y)
        stamp_s = mid_s + self.errors.clock_offset_s
        return tuple(Centroid(int(hip), float(x), float(y), stamp_s)
                     for hip, x, y in zip(hips[in_front][on_chip], x_px[on_chip], y_px[on_chip]))

    def _hook_context(self, elevation, mid_s, temperature_c, specific_force_tarf_m_per_s2, los_angle_deg):
        """The CameraContext of a frame for the camera's plug-in hooks; None for a camera without hooks."""
        if not (self.errors.plugins or self.errors.shift_plugins):
            return None
        context = CameraContext.at_rest(self.errors.camera, elevation, time_s=mid_s, temperature_c=temperature_c,
                                        los_angle_deg=los_angle_deg)
        if specific_force_tarf_m_per_s2 is not None:
            context = dataclasses.replace(context, specific_force_m_per_s2=np.reshape(
                np.asarray(specific_force_tarf_m_per_s2, dtype=float), (1, 3)))
        return context

    def _camera_from_tarf(self, elevation, context):
        """camera_from_tarf_dcm of a frame. Without hooks (no context) it depends on the elevation alone, which the
        coarse drive holds for most frames: then it is kept from the last frame at the same elevation."""
        if context is not None:
            return camera_from_tarf_dcm(self.errors, elevation, context)
        if self._mounting_at[0] != elevation:
            mounting = camera_from_tarf_dcm(self.errors, elevation)
            mounting.flags.writeable = False  # kept for the next frames
            self._mounting_at = (elevation, mounting)
        return self._mounting_at[1]

    def _update_candidates(self, mid_s, axis_irf):
        """Reselect stars when the camera axis leaves the selection margin; re-place them when stale."""
        margin_cos = np.cos(self._selection_margin_deg * RAD_PER_DEG)
        if self._selection_axis_irf is None or axis_irf @ self._selection_axis_irf < margin_cos:
            self.candidates = select_candidate_stars(
                self.scene, mid_s, axis_irf, self._field_radius_deg + self._selection_margin_deg,
                self.magnitude_limit_mag)
            self._candidate_hip = np.array([star.hip for star in self.candidates], dtype=np.int64)
            self._selection_axis_irf = axis_irf.copy()
            self._places_elapsed_s = None
        if self._places_elapsed_s is None or abs(mid_s - self._places_elapsed_s) > self._place_refresh_s:
            self._directions_irf = star_directions_irf(self.candidates, self.scene, mid_s)
            self._places_elapsed_s = mid_s
