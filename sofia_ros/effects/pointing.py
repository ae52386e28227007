"""Pointing geometry effects: Earth rotation, flexure, imagers, HIPO, atmosphere, timing (3, 4.1, 4.3, 6)."""

from __future__ import annotations

from sofia_ros.effects.base import EffectSpec, Parameter

EFFECTS: tuple[EffectSpec, ...] = (
    EffectSpec(
        'earth_rotation', 'earth', '4.1, eqs. 4.1-4.3',
        'The Earth turns under the telescope: a braked telescope senses 4.1-4.3 for the site latitude, '
        'heading and elevation; an inertial hold walks the fine drive at that rate.',
        (Parameter('rate_deg_per_h', 15.0411, 'deg/h', "Earth's rotation rate (4.1)", minimum=0.0, maximum=30.0),),
    ),
    EffectSpec(
        'heading_error', 'earth', '5.2.4, Table 5.7',
        'Error of the measured aircraft heading; the least-squares heading of Table 5.7 lies 3.2 deg '
        'from the GPS value.',
        (Parameter('heading_error_deg', 3.2, 'deg', 'true minus assumed heading', minimum=-180.0, maximum=180.0),),
    ),
    EffectSpec(
        'focal_plane_flexure', 'flexure', '3.4.1, Table 3.2, eqs. 3.21-3.25',
        'Gravity image motion at the focal plane from the FEM load cases of Table 3.2.',
        (Parameter('scale', 1.0, '1', 'multiplier on the Table 3.2 load matrix', minimum=-10.0, maximum=10.0),),
    ),
    EffectSpec(
        'imager_flexure', 'flexure', '3.4.1, Table 3.3, eqs. 3.26-3.29',
        'Gravity rotation of the head-ring imagers (FFI, WFI) from the FEM load cases of Table 3.3.',
        (
            Parameter('ffi_scale', 1.0, '1', 'multiplier on the FFI rows of Table 3.3', minimum=-10.0, maximum=10.0),
            Parameter('wfi_scale', 1.0, '1', 'multiplier on the WFI rows of Table 3.3', minimum=-10.0, maximum=10.0),
        ),
    ),
    EffectSpec(
        'fpi_internal_flexure', 'flexure', '6.2, Fig. 6.4',
        'FPI boresight motion relative to HIPO beyond the FEM prediction: 1.1" in XEL and < 0.27" in '
        'EL between 23 and 60 deg elevation (FEM: about 0.1"). Proportional to the LOS load, sin(el).',
        (
            Parameter('xel_arcsec_per_g', 2.32, 'arcsec/g', 'XEL boresight shift per 1 g load along -LOS',
                      minimum=-100.0, maximum=100.0),
            Parameter('el_arcsec_per_g', 0.4, 'arcsec/g', 'EL boresight shift per 1 g load along -LOS',
                      minimum=-100.0, maximum=100.0),
        ),
    ),
    EffectSpec(
        'imager_boresight_offset', 'imager', '3.3.1, Table 3.4 step 1',
        'Imager boresight (CCD centre) offset from the TARF origin, per imager (illustrative mounting '
        'magnitudes; the thesis prints none).',
        tuple(
            Parameter(f'{imager}_{axis}_arcsec', value, 'arcsec', f'{imager.upper()} boresight offset about {axis.upper()}',
                      minimum=-3600.0, maximum=3600.0)
            for imager, values in (('fpi', (10.0, -15.0)), ('ffi', (60.0, 45.0)), ('wfi', (300.0, -240.0)))
            for axis, value in zip(('el', 'xel'), values)
        ),
    ),
    EffectSpec(
        'imager_rotation_of_field', 'imager', '3.3.3, Table 3.4 step 4',
        'Rotation of each imager CCD about its optical axis against TARF (illustrative magnitudes).',
        (
            Parameter('fpi_deg', 0.5, 'deg', 'FPI rotation of field', minimum=-10.0, maximum=10.0),
            Parameter('ffi_deg', -0.8, 'deg', 'FFI rotation of field', minimum=-10.0, maximum=10.0),
            Parameter('wfi_deg', 1.2, 'deg', 'WFI rotation of field', minimum=-10.0, maximum=10.0),
        ),
    ),
    EffectSpec(
        'imager_scale_error', 'imager', 'Table 2.6, 3.3.1',
        'True image scale against the one the software assumes (Table 2.6, measured); defaults make '
        'the truth the design scales of 3.3.1 (WFI 21.39 vs 20.36"/px, FPI 0.554 vs 0.55"/px).',
        (
            Parameter('fpi_ppm', 7273.0, 'ppm', 'FPI true scale / assumed scale - 1',
                      minimum=-100000.0, maximum=100000.0),
            Parameter('ffi_ppm', 0.0, 'ppm', 'FFI true scale / assumed scale - 1', minimum=-100000.0, maximum=100000.0),
            Parameter('wfi_ppm', 50589.0, 'ppm', 'WFI true scale / assumed scale - 1',
                      minimum=-100000.0, maximum=100000.0),
        ),
    ),
    EffectSpec(
        'hipo_fiducial_error', 'imager', '3.3.1 footnote',
        'HIPO flange centre and CCD angle phi in error; defaults are the 2008 minus 2004 fiducials '
        '((542.8, 480.2) px, 39.81 deg against (559, 489) px, 40.181 deg).',
        (
            Parameter('center_x_px', -16.2, 'px', 'true minus assumed flange centre X', minimum=-100.0, maximum=100.0),
            Parameter('center_y_px', -8.8, 'px', 'true minus assumed flange centre Y', minimum=-100.0, maximum=100.0),
            Parameter('phi_deg', -0.371, 'deg', 'true minus assumed CCD angle phi', minimum=-10.0, maximum=10.0),
        ),
    ),
    EffectSpec(
        'atmospheric_refraction', 'atmosphere', '4.3.2, eqs. 4.33-4.35',
        'Refraction raises every star towards the zenith; defaults are the Waco weather of 2004-09-02 24:00 CDT.',
        (
            Parameter('temperature_c', 22.8, 'C', 'air temperature', shape=True, minimum=-80.0, maximum=60.0),
            Parameter('pressure_hpa', 996.3, 'hPa', 'air pressure', minimum=0.0, maximum=1100.0),
            Parameter('humidity', 0.74, '1', 'relative humidity', shape=True, minimum=0.0, maximum=1.0),
            Parameter('wavelength_um', 0.55, 'um', 'effective wavelength', shape=True, minimum=0.3, maximum=30.0),
        ),
    ),
    EffectSpec(
        'seeing', 'atmosphere', '6.1',
        'Centroid jitter from atmospheric seeing and image wander, 0.3" RMS per axis after drift removal.',
        (Parameter('rms_arcsec', 0.3, 'arcsec', 'centroid jitter per axis', minimum=0.0, maximum=10.0),),
    ),
    EffectSpec(
        'tracker_drift', 'imager', '6.3',
        'Residual centroid drift after drift estimation: linear plus sinusoid in FPI rows '
        '(1.4 px/min, 2.2 px amplitude, 5.2 min period).',
        (
            Parameter('linear_px_per_min', 1.4, 'px/min', 'linear drift of the FPI row centroid',
                      minimum=-100.0, maximum=100.0),
            Parameter('sine_amplitude_px', 2.2, 'px', 'amplitude of the sinusoidal drift', minimum=0.0, maximum=100.0),
            Parameter('sine_period_min', 5.2, 'min', 'period of the sinusoidal drift', shape=True,
                      minimum=0.1, maximum=1000.0),
            Parameter('sine_phase_deg', 0.0, 'deg', 'phase of the sinusoidal drift rate at the start of the record', shape=True,
                      minimum=-360.0, maximum=360.0),
        ),
    ),
    EffectSpec(
        'timestamp_offset', 'timing', '6.2',
        'Clock offset between HIPO time stamps and the TA housekeeping (read out manually in 2004; '
        'illustrative default).',
        (Parameter('offset_s', 1.0, 's', 'HIPO clock minus TA clock', minimum=-60.0, maximum=60.0),),
    ),
    EffectSpec(
        'accelerometer_bias', 'accelerometer', '2.4.2, Table 2.5',
        'Accelerometer bias per axis (Q-Flex QA-2000-10 specification: 4 mg).',
        (
            Parameter('el_mg', 4.0, 'mg', 'bias of the EL accelerometer', minimum=-100.0, maximum=100.0),
            Parameter('xel_mg', 4.0, 'mg', 'bias of the XEL accelerometer', minimum=-100.0, maximum=100.0),
            Parameter('los_mg', 4.0, 'mg', 'bias of the LOS accelerometer', minimum=-100.0, maximum=100.0),
        ),
    ),
    EffectSpec(
        'accelerometer_misalignment', 'accelerometer', '2.4.2, Table 2.5',
        'Accelerometer axes misalignment (specification: 105 urad).',
        (
            Parameter('about_el_urad', 105.0, 'urad', 'rotation about EL', minimum=-10000.0, maximum=10000.0),
            Parameter('about_xel_urad', 105.0, 'urad', 'rotation about XEL', minimum=-10000.0, maximum=10000.0),
            Parameter('about_los_urad', 105.0, 'urad', 'rotation about LOS', minimum=-10000.0, maximum=10000.0),
        ),
    ),
)
