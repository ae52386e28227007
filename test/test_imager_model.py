"""Camera truth model: stars on the sky to FPI/FFI/WFI/HIPO centroids, with each error effect pinned."""

import datetime as dt
import functools

import numpy as np
import pytest

from sofia_ros import flexure
from sofia_ros.errors import ConfigError, InvalidArgumentError, NotOrthonormalError, UnknownEffectError
from sofia_ros.frames import HIPO_2004, HIPO_2008, dcm_from_rotation_angles, pixel_to_vector
from sofia_ros.mount import hrf_from_irf_dcm, unit_vector_hrf
from sofia_ros.sensors.imager_model import (
    CAMERAS,
    ImagerTruth,
    Scene,
    camera_errors,
    camera_from_tarf_dcm,
    nominal_detector,
    predicted_centroid_px,
    refracted_directions_hrf,
    star_directions_irf,
)
from sofia_ros.sky import WACO_2004_SITE, WACO_2004_WEATHER, observed_directions_hrf, observed_place
from sofia_ros.units import ARCSEC_PER_RAD, RAD_PER_ARCSEC

CDT = dt.timezone(dt.timedelta(hours=-5))
# Table D.3 #2: Polaris at 31.68 deg altitude, refraction 88.2", Waco 2004-09-02 23:32:51 CDT.
SCENE = Scene(WACO_2004_SITE, dt.datetime(2004, 9, 2, 23, 32, 51, tzinfo=CDT))
POLARIS = 11767
ETA_CEP = 102422
EXPOSURE_S = 0.5
MID_S = EXPOSURE_S / 2.0  # a frame opening at 0 s shows the sky at mid-exposure
HIPO_PHI_RAD = np.radians(40.181)
HIPO_S_RAD_PER_PX = 1.5853e-6
CENTRES_PX = {'hipo': (559.0, 489.0), 'fpi': (511.5, 511.5), 'ffi': (511.5, 511.5), 'wfi': (511.5, 511.5)}
# Eqs. 3.5/3.6 solved for (X - X0, Y - Y0) of a star at TARF (u, v) = (0, +theta) - a telescope turned by
# +theta about EL - and (-theta, 0) - turned about XEL; imagers from eqs. 3.2/3.3 with u = X, v = Y.
SHIFT_PX_PER_RAD = {
    'hipo': {'el': np.array([-np.sin(HIPO_PHI_RAD), -np.cos(HIPO_PHI_RAD)]) / HIPO_S_RAD_PER_PX,
             'xel': np.array([-np.cos(HIPO_PHI_RAD), np.sin(HIPO_PHI_RAD)]) / HIPO_S_RAD_PER_PX},
    **{camera: {'el': np.array([0.0, 1.0]) / (scale * RAD_PER_ARCSEC),
                'xel': np.array([-1.0, 0.0]) / (scale * RAD_PER_ARCSEC)}
       for camera, scale in (('fpi', 0.55), ('ffi', 4.07), ('wfi', 20.36))},
}
AXIS_INDEX = {'el': 0, 'xel': 1, 'los': 2}


@functools.lru_cache(maxsize=None)
def star_irf(name, elapsed_s=MID_S, refracted=False):
    """IRF direction of a star from the direct ERFA chain (no caching inside the model)."""
    weather = WACO_2004_WEATHER if refracted else None
    return star_directions_irf([name], SCENE, elapsed_s, weather)[0]


def los_attitude(direction_irf):
    """A_TARF,IRF with its LOS (row w) on ``direction_irf`` and its EL axis horizontal at the epoch."""
    w = direction_irf / np.linalg.norm(direction_irf)
    u = np.cross([0.0, 0.0, 1.0], w)
    u /= np.linalg.norm(u)
    return np.array([u, np.cross(w, u), w])


def turned(attitude, axis, angle_arcsec):
    """The telescope turned by a small angle about one of its own TARF axes (B.19-B.22)."""
    angles = np.zeros(3)
    angles[AXIS_INDEX[axis]] = angle_arcsec * RAD_PER_ARCSEC
    return dcm_from_rotation_angles(angles) @ attitude


def frame(camera, effects, attitude, elevation_deg=31.7, elapsed_s=0.0, **options):
    """One frame of a fresh camera truth model."""
    truth = ImagerTruth(camera, effects, SCENE, exposure_s=EXPOSURE_S, **options)
    return truth.centroids(elapsed_s, attitude, elevation_deg)


def pixel_of(centroids, hip=POLARIS):
    (found,) = [c for c in centroids if c.hip == hip]
    return np.array([found.x_px, found.y_px])


@pytest.mark.parametrize('camera', CAMERAS)
def test_star_on_the_los_lands_on_the_flange_centre_and_the_imager_centres(camera):
    pixel = pixel_of(frame(camera, {}, los_attitude(star_irf('Polaris'))))
    np.testing.assert_allclose(pixel, CENTRES_PX[camera], rtol=0, atol=1e-6)


@pytest.mark.parametrize('axis', ['el', 'xel'])
@pytest.mark.parametrize('camera', CAMERAS)
def test_small_telescope_rotation_moves_the_star_as_eqs_3_2_to_3_7_say(camera, axis):
    # +20" about EL: HIPO 61.2 px along (-sin phi, -cos phi), imagers +Y; about XEL: -X on the imagers.
    angle_arcsec = 20.0
    attitude = los_attitude(star_irf('Polaris'))
    shift = pixel_of(frame(camera, {}, turned(attitude, axis, angle_arcsec))) - CENTRES_PX[camera]
    np.testing.assert_allclose(shift, SHIFT_PX_PER_RAD[camera][axis] * angle_arcsec * RAD_PER_ARCSEC,
                               rtol=0, atol=1e-5)


def test_inertially_fixed_polaris_moves_only_with_the_change_of_refraction():
    # Attitude fixed against IRF for 60 s. Without refraction Polaris stays put: the direct ERFA
    # chain moves it by 0.0015" (ERFA's Earth rotation against the 15.0411 deg/h of section 4.1 and
    # the turning diurnal aberration). Refraction is fixed in HRF, which turns under IRF: Polaris
    # moves by 0.386" = 1.18 HIPO px, exactly as the direct ERFA + Stone chain says.
    attitude = los_attitude(star_irf('Polaris'))
    truth = ImagerTruth('hipo', {}, SCENE, exposure_s=EXPOSURE_S)
    still = pixel_of(truth.centroids(60.0, attitude, 31.7)) - pixel_of(truth.centroids(0.0, attitude, 31.7))
    assert np.linalg.norm(still) * HIPO_2004.scale_arcsec_per_px < 0.003
    direct_arcsec = np.linalg.norm(star_irf('Polaris', MID_S + 60.0) - star_irf('Polaris')) * ARCSEC_PER_RAD
    assert direct_arcsec < 0.003

    truth = ImagerTruth('hipo', {'atmospheric_refraction': {}}, SCENE, exposure_s=EXPOSURE_S)
    moved = pixel_of(truth.centroids(60.0, attitude, 31.7)) - pixel_of(truth.centroids(0.0, attitude, 31.7))
    expected = (predicted_centroid_px('hipo', star_irf('Polaris', MID_S + 60.0, True), attitude)
                - predicted_centroid_px('hipo', star_irf('Polaris', MID_S, True), attitude))
    np.testing.assert_allclose(moved, expected, rtol=0, atol=0.01)
    assert np.linalg.norm(moved) * HIPO_2004.scale_arcsec_per_px == pytest.approx(0.386, abs=0.005)


def test_held_places_stay_within_3_mas_of_the_direct_erfa_chain():
    # Candidate places are refreshed every 60 s; just before a refresh they are oldest.
    attitude = los_attitude(star_irf('Polaris'))
    for effects, refracted in (({}, False), ({'atmospheric_refraction': {}}, True)):
        truth = ImagerTruth('fpi', effects, SCENE, exposure_s=EXPOSURE_S)
        truth.centroids(0.0, attitude, 31.7)
        held = pixel_of(truth.centroids(59.9, attitude, 31.7))
        direct = predicted_centroid_px('fpi', star_irf('Polaris', MID_S + 59.9, refracted), attitude)
        assert np.linalg.norm(held - direct) * 0.55 < 0.003


def test_refraction_raises_polaris_by_its_stone_angle_towards_the_zenith():
    # Polaris at 31.7 deg: refraction on moves its HIPO centroid by R = 88.2" (Table D.3: 88.2")
    # towards the zenith as seen in TARF.
    attitude = los_attitude(star_irf('Polaris'))
    off = pixel_of(frame('hipo', {}, attitude))
    on = pixel_of(frame('hipo', {'atmospheric_refraction': {}}, attitude))
    seen_off, seen_on = pixel_to_vector(np.array([off, on]), HIPO_2004)
    place = observed_place('Polaris', WACO_2004_SITE, SCENE.utc_at(MID_S), WACO_2004_WEATHER)
    moved_arcsec = np.arccos(seen_off @ seen_on) * ARCSEC_PER_RAD
    assert moved_arcsec == pytest.approx(place.refraction_arcsec, abs=0.01)
    assert place.refraction_arcsec == pytest.approx(88.2, abs=0.1)
    zenith_tarf = attitude @ hrf_from_irf_dcm(SCENE.earth_latitude_deg, MID_S).T @ [0.0, 0.0, 1.0]
    towards_zenith = zenith_tarf[:2] / np.linalg.norm(zenith_tarf[:2])  # tangent plane at the LOS
    direction = (seen_on - seen_off)[:2] / np.linalg.norm((seen_on - seen_off)[:2])
    assert direction @ towards_zenith > np.cos(np.radians(0.01))


def test_tabulated_refraction_matches_stone_within_a_milliarcsecond():
    # Per frame, refraction comes from a 0.02 deg table of Stone's R(z); the direct path evaluates it.
    hips = [POLARIS, ETA_CEP, 47193]  # 31.7, 59.7 and 22.9 deg altitude
    unrefracted = observed_directions_hrf(hips, WACO_2004_SITE, SCENE.epoch_utc)
    direct = observed_directions_hrf(hips, WACO_2004_SITE, SCENE.epoch_utc, WACO_2004_WEATHER)
    tabulated = refracted_directions_hrf(unrefracted, WACO_2004_SITE, WACO_2004_WEATHER)
    assert np.max(np.linalg.norm(tabulated - direct, axis=1)) * ARCSEC_PER_RAD < 1e-3
    with pytest.raises(InvalidArgumentError, match='above 10 deg altitude'):
        refracted_directions_hrf(unit_vector_hrf(5.0, 0.0), WACO_2004_SITE, WACO_2004_WEATHER)


def boresight_against_hipo_arcsec(camera, effects, elevation_deg):
    """(EL, XEL) ["] by which the camera sees a star held on HIPO's flange centre (6.2, Fig. 6.4)."""
    hipo_mounting = camera_from_tarf_dcm(camera_errors('hipo', effects), elevation_deg)
    attitude = hipo_mounting.T @ los_attitude(star_irf('Polaris'))
    hipo = pixel_of(frame('hipo', effects, attitude, elevation_deg))
    np.testing.assert_allclose(hipo, CENTRES_PX['hipo'], rtol=0, atol=1e-6)
    seen = pixel_of(frame(camera, effects, attitude, elevation_deg))
    u, v, w = pixel_to_vector(seen, nominal_detector(camera))
    # A camera turned by (dEL, dXEL) against HIPO sees HIPO's axis at (-dXEL, +dEL, 1) (B.19-B.22).
    return np.array([v / w, -u / w]) * ARCSEC_PER_RAD


def boresight_change_arcsec(camera, effects):
    """Change of the camera's (EL, XEL) view of HIPO's axis from 23 to 60 deg elevation (6.2)."""
    return (boresight_against_hipo_arcsec(camera, effects, 60.0)
            - boresight_against_hipo_arcsec(camera, effects, 23.0))


@pytest.mark.parametrize('camera, expected_arcsec', [('ffi', (-3.24, 8.96)), ('wfi', (-2.79, 8.75))])
def test_head_ring_imagers_show_the_fem_differential_flexure_from_23_to_60_deg(camera, expected_arcsec):
    # Section 6.2: the FFI boresight moves against HIPO by about 9" in XEL over 23-60 deg; the FEM
    # (Tables 3.2, 3.3) predicts 8.96" XEL and -3.24" EL (6.2 measured about 8" in EL).
    effects = {'focal_plane_flexure': {}, 'imager_flexure': {}}
    change = boresight_change_arcsec(camera, effects)
    np.testing.assert_allclose(change, expected_arcsec, rtol=0, atol=0.01)
    fem = flexure.differential_imager_rotation_arcsec(camera, flexure.gravity_load_tarf(60.0),
                                                      flexure.gravity_load_tarf(23.0))
    # The linear FEM sum differs by < 0.005": the imager's ~60" flexure about LOS turns its ~40" offset.
    np.testing.assert_allclose(change, fem, rtol=0, atol=0.005)


def test_fpi_follows_the_focal_plane_except_for_its_internal_flexure():
    # The FPI sees through the telescope: focal-plane flexure moves it with HIPO. Its internal
    # flexure adds 1.10" XEL and 0.19" EL over 23-60 deg (6.2: 1.1" XEL, < 0.27" EL).
    focal_plane = {'focal_plane_flexure': {}}
    np.testing.assert_allclose(boresight_change_arcsec('fpi', focal_plane), 0.0, atol=1e-4)
    change = boresight_change_arcsec('fpi', {**focal_plane, 'fpi_internal_flexure': {}})
    np.testing.assert_allclose(change, (0.190, 1.103), rtol=0, atol=0.002)
    assert abs(change[0]) < 0.27


def test_hipo_fiducial_error_moves_the_flange_centre_and_turns_the_pattern_by_phi():
    # Defaults: the 2008 fiducials are the truth while the 2004 ones are assumed (3.3.1 footnote).
    effects = {'hipo_fiducial_error': {}}
    attitude = los_attitude(star_irf('Polaris'))
    centre = pixel_of(frame('hipo', effects, attitude))
    np.testing.assert_allclose(centre, HIPO_2008.center_px, rtol=0, atol=1e-6)
    shift = pixel_of(frame('hipo', effects, turned(attitude, 'el', 20.0))) - centre
    nominal = SHIFT_PX_PER_RAD['hipo']['el']
    # The EL direction (-sin phi, -cos phi) lies at -90 deg - phi: phi 0.371 deg smaller turns it +0.371 deg.
    turn_deg = np.degrees(np.arctan2(shift[1], shift[0]) - np.arctan2(nominal[1], nominal[0]))
    assert turn_deg == pytest.approx(0.371, abs=1e-6)
    assert np.linalg.norm(shift) == pytest.approx(np.linalg.norm(nominal) * 20.0 * RAD_PER_ARCSEC,
                                                  rel=1e-6)


def test_imager_boresight_offset_rotation_of_field_and_scale_error():
    attitude = los_attitude(star_irf('Polaris'))
    # Boresight offset (FFI defaults 60" EL, 45" XEL): TARF's LOS lands where a telescope turned by
    # that would put it.
    centre = pixel_of(frame('ffi', {'imager_boresight_offset': {}}, attitude))
    np.testing.assert_allclose(centre, (511.5 - 45.0 / 4.07, 511.5 + 60.0 / 4.07), rtol=0, atol=1e-4)
    # Rotation of field (FFI default -0.8 deg about LOS): the +EL shift (0, d) turns to d (sin g, cos g).
    shift = pixel_of(frame('ffi', {'imager_rotation_of_field': {}}, turned(attitude, 'el', 100.0))) - 511.5
    gamma = np.radians(-0.8)
    np.testing.assert_allclose(shift, 100.0 / 4.07 * np.array([np.sin(gamma), np.cos(gamma)]),
                               rtol=0, atol=1e-4)
    # Scale error (WFI default +50589 ppm): the true scale is the 3.3.1 value, 20.36 x 1.050589 = 21.39 "/px.
    shift = pixel_of(frame('wfi', {'imager_scale_error': {}}, turned(attitude, 'xel', 300.0))) - 511.5
    expected_px = -np.tan(300.0 * RAD_PER_ARCSEC) / (20.36 * 1.050589 * RAD_PER_ARCSEC)
    np.testing.assert_allclose(shift, (expected_px, 0.0), rtol=0, atol=1e-6)


def test_seeing_jitter_has_the_parameter_rms_and_is_reproducible():
    # 6.1: 0.3" RMS per axis. 2000 seeded frames of HIPO give the sample RMS within 10 %.
    attitude = los_attitude(star_irf('Polaris'))
    pixels = []
    for seed in (7, 7, 8):
        truth = ImagerTruth('hipo', {'seeing': {}}, SCENE, exposure_s=EXPOSURE_S, seed=seed)
        pixels.append(np.array([pixel_of(truth.centroids(0.5 * i, attitude, 31.7)) for i in range(2000)]))
    np.testing.assert_array_equal(pixels[0], pixels[1])
    assert not np.allclose(pixels[0], pixels[2])
    rms_px = np.sqrt(np.mean((pixels[0] - CENTRES_PX['hipo']) ** 2, axis=0))
    np.testing.assert_allclose(rms_px * HIPO_2004.scale_arcsec_per_px, 0.3, rtol=0.1)


def test_timestamp_offset_shifts_hipo_stamps_only():
    # Stamps are the mid-exposure (6.1); the HIPO clock runs offset_s ahead of the TA's (6.2).
    attitude = los_attitude(star_irf('Polaris'))
    effects = {'timestamp_offset': {'offset_s': 1.5}}
    (hipo,) = [c for c in frame('hipo', effects, attitude, elapsed_s=10.0) if c.hip == POLARIS]
    (fpi,) = [c for c in frame('fpi', effects, attitude, elapsed_s=10.0) if c.hip == POLARIS]
    assert hipo.stamp_s == 10.0 + MID_S + 1.5
    assert fpi.stamp_s == 10.0 + MID_S


def test_predicted_centroids_are_the_truth_without_errors():
    # The TASCU model: nominal detector and the mounting it believes; with the true mounting given,
    # it reproduces a truth that has mounting and flexure errors but no detector errors.
    attitude = los_attitude(star_irf('Polaris'))
    frame_px = frame('wfi', {}, attitude)
    assert len(frame_px) > 10
    directions = star_directions_irf([c.hip for c in frame_px], SCENE, MID_S)
    np.testing.assert_allclose(predicted_centroid_px('wfi', directions, attitude),
                               [(c.x_px, c.y_px) for c in frame_px], rtol=0, atol=1e-6)
    effects = {'imager_boresight_offset': {}, 'imager_rotation_of_field': {}, 'imager_flexure': {}}
    frame_px = frame('wfi', effects, attitude, elevation_deg=45.0)
    mounting = camera_from_tarf_dcm(camera_errors('wfi', effects), 45.0)
    directions = star_directions_irf([c.hip for c in frame_px], SCENE, MID_S)
    np.testing.assert_allclose(predicted_centroid_px('wfi', directions, attitude, mounting),
                               [(c.x_px, c.y_px) for c in frame_px], rtol=0, atol=1e-6)


def test_slewing_beyond_the_margin_selects_the_new_field():
    truth = ImagerTruth('wfi', {}, SCENE, exposure_s=EXPOSURE_S)
    truth.centroids(0.0, los_attitude(star_irf('Polaris')), 31.7)
    assert POLARIS in {star.hip for star in truth.candidates}
    on_eta_cep = truth.centroids(0.0, los_attitude(star_irf('Eta Cep')), 59.7)
    np.testing.assert_allclose(pixel_of(on_eta_cep, ETA_CEP), CENTRES_PX['wfi'], rtol=0, atol=1e-6)
    assert POLARIS not in {star.hip for star in truth.candidates}
    assert all(star.hp_magnitude <= 8.0 for star in truth.candidates)


def test_an_empty_field_gives_an_empty_frame():
    # 1 deg from Polaris no Hipparcos star lies within the FPI's 0.11 deg field plus a 0.05 deg margin.
    attitude = turned(los_attitude(star_irf('Polaris')), 'el', 3600.0)
    truth = ImagerTruth('fpi', {'atmospheric_refraction': {}, 'seeing': {}}, SCENE, exposure_s=EXPOSURE_S,
                        selection_margin_deg=0.05)
    assert truth.centroids(0.0, attitude, 31.7) == ()
    assert truth.candidates == ()


def test_wfi_around_polaris_images_many_stars_with_every_effect_on():
    # Every effect on, WFI around Polaris: 45 candidates, 14 on the chip (frame cost: bench/bench_imager.py).
    names = ('atmospheric_refraction', 'seeing', 'focal_plane_flexure', 'imager_flexure',
             'imager_boresight_offset', 'imager_rotation_of_field', 'imager_scale_error')
    effects = {name: {} for name in names}
    truth = ImagerTruth('wfi', effects, SCENE, exposure_s=EXPOSURE_S)
    attitude = los_attitude(star_irf('Polaris'))
    assert len(truth.centroids(0.0, attitude, 31.7)) >= 10
    assert len(truth.candidates) >= 20
    frames = [truth.centroids(0.5 * i, attitude, 31.7) for i in range(4)]
    assert all(len(frame) == len(frames[0]) for frame in frames)


def test_bad_input_is_refused():
    attitude = los_attitude(star_irf('Polaris'))
    with pytest.raises(InvalidArgumentError, match="camera must be one of .* got 'nirspec'"):
        ImagerTruth('nirspec', {}, SCENE, exposure_s=EXPOSURE_S)
    with pytest.raises(ConfigError, match="effect 'seeing': unknown parameter 'rms_px'"):
        ImagerTruth('hipo', {'seeing': {'rms_px': 1.0}}, SCENE, exposure_s=EXPOSURE_S)
    with pytest.raises(UnknownEffectError, match="unknown effect 'sky_glow'"):
        ImagerTruth('hipo', {'sky_glow': {}}, SCENE, exposure_s=EXPOSURE_S)
    with pytest.raises(ConfigError, match='effects must map effect names'):
        ImagerTruth('hipo', ['seeing'], SCENE, exposure_s=EXPOSURE_S)
    with pytest.raises(InvalidArgumentError, match='exposure_s must be > 0'):
        ImagerTruth('hipo', {}, SCENE, exposure_s=0.0)
    with pytest.raises(InvalidArgumentError, match='scene must be a Scene'):
        ImagerTruth('hipo', {}, WACO_2004_SITE, exposure_s=EXPOSURE_S)
    with pytest.raises(InvalidArgumentError, match='epoch_utc must be a timezone-aware'):
        Scene(WACO_2004_SITE, dt.datetime(2004, 9, 3, 4, 32, 51))
    truth = ImagerTruth('hipo', {}, SCENE, exposure_s=EXPOSURE_S)
    with pytest.raises(InvalidArgumentError, match='tarf_from_irf contains NaN'):
        truth.centroids(0.0, np.full((3, 3), np.nan), 31.7)
    with pytest.raises(NotOrthonormalError, match='tarf_from_irf is not orthonormal'):
        truth.centroids(0.0, 1.1 * attitude, 31.7)
    with pytest.raises(InvalidArgumentError, match='elevation_deg must be in'):
        truth.centroids(0.0, attitude, 95.0)
    with pytest.raises(InvalidArgumentError, match='elapsed_s contains NaN'):
        truth.centroids(float('nan'), attitude, 31.7)
    with pytest.raises(InvalidArgumentError, match='vector must point into the detector'):
        predicted_centroid_px('hipo', -star_irf('Polaris'), attitude)
