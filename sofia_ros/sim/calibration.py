"""Calibration node core: the Table 3.4 alignment sequence as practised in 6.1 and 6.4.

Drift estimation on the tracked star, LOS rotations about a star at the flange centre
(maneuver 2), EL/XEL rotations across HIPO's field (maneuver 3), each repeated with
several frames before and after and selected by motion status; the least-squares
solver of 3.3.2 on all maneuvers at once; the new A_TARF,GYRF pushed to the TASCU as
a parameter; a verification block that either accepts the matrix or starts another
iteration (Table D.1). Boresights of the imagers at the reference elevation
(maneuver 1) and their rotations of field (maneuver 4) follow. The sequence is a
generator that waits one tick at every ``yield``.
"""

from __future__ import annotations

import datetime as dt
from dataclasses import asdict, dataclass
from functools import cached_property
from typing import ClassVar

import numpy as np
import yaml
from diagnostic_msgs.msg import DiagnosticStatus

from sofia_ros import messages as m
from sofia_ros.calibration.accuracy import sigma_beta_from_length_rad, sigma_r_rad
from sofia_ros.calibration.boresights import boresight_shift_arcsec, flexure_fit
from sofia_ros.calibration.maneuver_records import maneuver_record
from sofia_ros.calibration.solvers import Maneuver, fit_alignment
from sofia_ros.control.attitude import rotation_error_rad
from sofia_ros.errors import CalibrationAbort, InvalidArgumentError
from sofia_ros.graph_nodes import IMAGERS
from sofia_ros.sensors.imager_model import nominal_detector
from sofia_ros.sim.sequence import (
    TOPICS,
    SequenceCore,
    check_plan_limits,
    elements_from_yaml,
    elements_to_yaml,
    fine_drive_los,
    hold_duration,
    observing_elevation,
    thermal_rate,
    thermal_target,
)
from sofia_ros.sky import TELESCOPE_MIN_ELEVATION_DEG, WACO_2004_WEATHER, visible_stars
from sofia_ros.topics import CD_JOINT, FD_JOINTS
from sofia_ros.units import ARCSEC_PER_RAD, RAD_PER_DEG

__all__ = ['AlignmentPlan', 'CalibrationCore', 'ALIGNMENT_ELEMENTS', 'ManeuversAt', 'LosRotations', 'AlignmentHold',
           'TemperatureHold']

_FD_MARGIN_DEG = 2.9
#: Where an EL/XEL rotation may take the star from HIPO's centre, arcsec: its shorter half-field less the detector
#: margin a plan's positions keep (sim.sequence.detector_offset).
_HIPO_HALF_FIELD_ARCSEC = (0.9 * nominal_detector('hipo').scale_arcsec_per_px
                           * min(nominal_detector('hipo').width_px, nominal_detector('hipo').height_px) / 2.0)
#: Stars for the elevation series: bright enough for every camera, within the fine drive's XEL reach.
_SERIES_MAX_HP_MAG = 6.5
_SERIES_REACH_DEG = 1.5
_MIN_REPETITIONS_FOR_DRIFT_FIT = 4
#: A plan element at an elevation stays on the current star within this much of it, else takes a star this close.
_ELEVATION_TOLERANCE_DEG = 3.0


# --- plan elements (docs/plans.md): flown after the sequence, in the order the plan lists them ----------
def _optional_elevation(value):
    return None if value is None else observing_elevation('elevation_deg', value)


@dataclass(frozen=True)
class ManeuversAt:
    """Table 3.4's LOS and EL/XEL moves (maneuvers 2 and 3) repeated on a star near another elevation."""

    kind: ClassVar[str] = 'maneuvers'
    elevation_deg: float
    #: moves per axis (None: the plan's repetitions)
    repetitions: int | None = None

    def __post_init__(self):
        object.__setattr__(self, 'elevation_deg', observing_elevation('elevation_deg', self.elevation_deg))
        if self.repetitions is not None and (isinstance(self.repetitions, bool)
                                             or not isinstance(self.repetitions, int) or self.repetitions < 1):
            raise InvalidArgumentError(f'repetitions must be an integer >= 1, got {self.repetitions!r}')


@dataclass(frozen=True)
class LosRotations:
    """LOS rotations (maneuver 2) through the fine-drive LOS angles listed, each step one measured move."""

    kind: ClassVar[str] = 'los_rotations'
    #: fine-drive LOS angles, deg: the first is reached unmeasured, every later one by a measured rotation
    angles_deg: tuple
    #: on a star near this elevation (None: where the telescope is)
    elevation_deg: float | None = None

    def __post_init__(self):
        if not isinstance(self.angles_deg, (list, tuple)) or len(self.angles_deg) < 2:
            raise InvalidArgumentError(f'angles_deg must list at least two LOS angles, got {self.angles_deg!r}')
        angles = tuple(fine_drive_los(f'angles_deg[{index}]', angle) for index, angle in enumerate(self.angles_deg))
        if any(after == before for before, after in zip(angles, angles[1:])):
            raise InvalidArgumentError(f'angles_deg {list(angles)} repeats an angle: a rotation of 0 deg '
                                       'measures nothing')
        object.__setattr__(self, 'angles_deg', angles)
        object.__setattr__(self, 'elevation_deg', _optional_elevation(self.elevation_deg))


@dataclass(frozen=True)
class AlignmentHold:
    """The star held at HIPO's centre at one fine-drive LOS angle for a while, every camera recording."""

    kind: ClassVar[str] = 'hold'
    duration_s: float
    #: fine-drive LOS angle during the hold, deg
    los_deg: float = 0.0
    #: on a star near this elevation (None: where the telescope is)
    elevation_deg: float | None = None

    def __post_init__(self):
        object.__setattr__(self, 'duration_s', hold_duration('duration_s', self.duration_s))
        object.__setattr__(self, 'los_deg', fine_drive_los('los_deg', self.los_deg))
        object.__setattr__(self, 'elevation_deg', _optional_elevation(self.elevation_deg))


@dataclass(frozen=True)
class TemperatureHold:
    """A hold while the truth's thermal control drives the temperature toward a setpoint (a plateau or a ramp)."""

    kind: ClassVar[str] = 'temperature'
    #: the setpoint, deg C: within the truth's scenario.thermal_control range (checked with the truth)
    target_c: float
    duration_s: float
    #: how fast the setpoint moves from the temperature to target_c, deg C/h (None: the truth's largest, a plateau)
    rate_c_per_h: float | None = None
    #: fine-drive LOS angle during the hold, deg
    los_deg: float = 0.0
    #: on a star near this elevation (None: where the telescope is)
    elevation_deg: float | None = None

    def __post_init__(self):
        object.__setattr__(self, 'target_c', thermal_target('target_c', self.target_c))
        object.__setattr__(self, 'duration_s', hold_duration('duration_s', self.duration_s))
        object.__setattr__(self, 'rate_c_per_h', thermal_rate('rate_c_per_h', self.rate_c_per_h))
        object.__setattr__(self, 'los_deg', fine_drive_los('los_deg', self.los_deg))
        object.__setattr__(self, 'elevation_deg', _optional_elevation(self.elevation_deg))


#: the alignment's plan elements by the name a plan file gives them
ALIGNMENT_ELEMENTS = {element.kind: element for element in (ManeuversAt, LosRotations, AlignmentHold, TemperatureHold)}


@dataclass(frozen=True)
class AlignmentPlan:
    """Size of the alignment campaign (6.1: six repetitions, three frames, 5 deg LOS, 4.8' EL/XEL)."""

    #: the campaign this dataclass plans (its name in campaigns.registry)
    campaign: ClassVar[str] = 'alignment'
    repetitions: int = 6
    frames_per_position: int = 3
    los_angle_deg: float = 5.0
    elxel_length_arcmin: float = 4.8
    drift_track_s: float = 60.0
    verification_repetitions: int = 2
    max_iterations: int = 3
    timeout_s: float = 120.0
    #: elevations of the boresight series (Table 3.5, 6.2: 23-60 deg); empty to skip it
    flexure_elevations_deg: tuple = (23.0, 40.0, 50.0, 59.0)
    #: the plan elements flown after the sequence (ALIGNMENT_ELEMENTS, docs/plans.md) as YAML text: one
    #: string, so that the plan still passes as node parameters (plan.elements_yaml)
    elements_yaml: str = ''

    def __post_init__(self):
        check_plan_limits(self)
        # The EL/XEL rotations carry the star across HIPO's field, from -L/2 to +L/2 (_elxel_block).
        longest_arcmin = 2.0 * _HIPO_HALF_FIELD_ARCSEC / 60.0
        if not 0.0 < self.elxel_length_arcmin <= longest_arcmin:
            raise InvalidArgumentError(f'elxel_length_arcmin must be > 0 and <= {longest_arcmin:.2f} arcmin, the '
                                       f'rotations crossing HIPO\'s field, got {self.elxel_length_arcmin:g}')
        if not 0.0 < self.los_angle_deg <= 2 * _FD_MARGIN_DEG - 0.5:
            raise InvalidArgumentError(f'los_angle_deg must be in (0, {2 * _FD_MARGIN_DEG - 0.5}] to fit the '
                                       f'+-3 deg fine drive, got {self.los_angle_deg}')
        for elevation_deg in self.flexure_elevations_deg:
            observing_elevation('flexure_elevations_deg', elevation_deg)
        # Parsed now (a bad element is refused before the run) and kept in one spelling, so equal plans compare equal.
        object.__setattr__(self, 'elements_yaml',
                           elements_to_yaml(elements_from_yaml(self.elements_yaml, ALIGNMENT_ELEMENTS, self.campaign)))

    @cached_property
    def elements(self):
        """The plan elements, parsed from ``elements_yaml``."""
        return elements_from_yaml(self.elements_yaml, ALIGNMENT_ELEMENTS, self.campaign)


class CalibrationCore(SequenceCore):
    """The alignment sequence: commands the maneuvers, solves the DCMs, pushes them to the TASCU, verifies."""

    def __init__(self, plan=None, scenario=None):
        super().__init__(plan or AlignmentPlan(), scenario)
        self.block = 0
        self.record = {'iterations': []}

    def _run(self):
        self._progress('acquire')
        yield from self._locked()
        yield from self._wait(lambda: any(stars for _, stars in self.frames['hipo']), 'a star in HIPO')
        _, stars = next(frame for frame in self.frames['hipo'] if frame[1])
        centre = nominal_detector('hipo').center_px
        self.star_hip, x_px, y_px = min(stars, key=lambda s: np.hypot(s[1] - centre[0], s[2] - centre[1]))
        yield from self._centre_star()
        yield from self._define_imager_boresights()
        for iteration in range(1, self.plan.max_iterations + 1):
            accepted = yield from self._iteration(iteration)
            if accepted:
                break
        else:
            raise CalibrationAbort(f'no alignment accepted after {self.plan.max_iterations} iterations')
        yield from self._imager_rotation_of_field()
        if self.plan.flexure_elevations_deg and self.scenario is not None:
            yield from self._flexure_series()
        yield from self._fly_elements()
        self._progress('finished')
        self.outbox.append((TOPICS['result'].name, m.string_msg(yaml.safe_dump(self.result(), sort_keys=False))))

    def _centre_star(self):
        yield from self._recentre_los()
        pixel, _ = yield from self._star_frames('hipo', 1)
        yield from self._command('mtbs_centroid', self._point_message('hipo', pixel))
        yield from self._locked()

    def _define_imager_boresights(self):
        """Maneuver 1 of Table 3.4: where the star at TARF's origin appears in each imager."""
        self._progress('boresight')
        boresights = {}
        for camera in IMAGERS:
            pixel, _ = yield from self._star_frames(camera, self.plan.frames_per_position)
            boresights[f'boresight.{camera}_px'] = [float(pixel[0]), float(pixel[1])]
        yield from self._push(boresights)
        self.record['boresight_px'] = {key.split('.')[1][:-3]: value for key, value in boresights.items()}

    def _estimate_drift(self):
        self.block += 1  # maneuvers after one drift estimation share one residual drift (6.1)
        self._progress('drift')
        yield from self._centre_star()
        pixel, _ = yield from self._star_frames('hipo', 1)
        yield from self._command('track', self._point_message('hipo', pixel, self.plan.drift_track_s))
        yield from self._centre_star()

    def _maneuver(self, axis, angle_rad, camera='hipo'):
        start, start_s = yield from self._star_frames(camera, self.plan.frames_per_position)
        rotation = np.zeros(3)
        rotation['el xel los'.split().index(axis)] = angle_rad
        yield from self._move(rotation)
        end, end_s = yield from self._star_frames(camera, self.plan.frames_per_position)
        # On an imager the gyros are already aligned: the fit then gives A_XYIRF,TARF (3.3.3).
        active = self.active_alignment if camera == 'hipo' else np.eye(3)
        return Maneuver(axis, angle_rad, start, end, active, end_s - start_s, self.block)

    def _los_block(self, repetitions):
        """LOS rotations alternating in sign, keeping the fine drive inside its travel (6.1)."""
        angle_rad = self.plan.los_angle_deg * RAD_PER_DEG
        maneuvers = []
        for _ in range(repetitions):
            fd_los_deg = self.joints.get(FD_JOINTS[2], 0.0) / RAD_PER_DEG
            sign = -1.0 if fd_los_deg > 0.0 else 1.0
            if abs(fd_los_deg + sign * self.plan.los_angle_deg) > _FD_MARGIN_DEG:
                # Pre-position (not measured) so the rotation runs across the travel, from -+half to +-half.
                half_deg = self.plan.los_angle_deg / 2.0
                yield from self._move(np.array([0.0, 0.0, (-sign * half_deg - fd_los_deg) * RAD_PER_DEG]))
            maneuvers.append((yield from self._maneuver('los', sign * angle_rad)))
        return maneuvers

    def _elxel_block(self, repetitions, camera='hipo'):
        """EL and XEL rotations of L across the field, alternating in sign (maneuver 3, 6.1)."""
        length_rad = self.plan.elxel_length_arcmin / 60.0 * RAD_PER_DEG
        maneuvers = []
        for index, axis in enumerate(('el', 'xel')):
            yield from self._centre_star()
            offset = np.zeros(3)
            offset[index] = -length_rad / 2.0
            yield from self._move(offset)
            for repetition in range(repetitions):
                sign = 1.0 if repetition % 2 == 0 else -1.0
                maneuvers.append((yield from self._maneuver(axis, sign * length_rad, camera)))
        yield from self._centre_star()
        return maneuvers

    def _iteration(self, iteration):
        self._progress('iteration', {'iteration': iteration})
        yield from self._estimate_drift()
        los = yield from self._los_block(self.plan.repetitions)
        tilt = self._fit('los_tilt', los, solve_for=('el', 'xel'))
        yield from self._set_alignment(tilt.dcm)
        yield from self._estimate_drift()
        elxel = yield from self._elxel_block(self.plan.repetitions)
        full = self._fit('gyro_alignment', los + elxel)
        yield from self._set_alignment(full.dcm)
        self._progress('verify', {'iteration': iteration})
        yield from self._estimate_drift()
        check = (yield from self._los_block(2 * self.plan.verification_repetitions)) + \
                (yield from self._elxel_block(2 * self.plan.verification_repetitions))
        verification = self._fit('verification', check, fit_drift=False)
        # The rotation angles (EL, XEL, LOS, B.19-B.22) that turn the accepted matrix into the verification's.
        correction = rotation_error_rad(full.dcm, verification.dcm)
        accepted = bool(np.all(np.abs(correction) <= 3.0 * verification.sigma_rad))
        self.record['iterations'].append({
            'iteration': iteration,
            'los_maneuvers': len(los), 'elxel_maneuvers': len(elxel),
            'fitted_alignment': full.dcm.tolist(),
            'fitted_sigma_arcsec': (full.sigma_rad * ARCSEC_PER_RAD).tolist(),
            'centroid_sigma_px': full.sigma_c_px,
            'residual_drift_fitted': self._fit_drift,
            'residual_drift_px_per_s': full.drift_px_per_s.tolist(),
            'verification_correction_arcsec': (correction * ARCSEC_PER_RAD).tolist(),
            'verification_sigma_arcsec': (verification.sigma_rad * ARCSEC_PER_RAD).tolist(),
            'accepted': accepted,
        })
        self.final_fit = full
        if not accepted:
            yield from self._set_alignment(verification.dcm)
        return accepted

    def _fit(self, purpose, maneuvers, *, solve_for=('el', 'xel', 'los'), fit_drift=None, camera='hipo'):
        """Solve (3.3.2) and publish the inputs so that the fit can be repeated offline from the bag."""
        fit_drift = self._fit_drift if fit_drift is None else fit_drift
        self.outbox.append((TOPICS['maneuvers'].name, m.string_msg(yaml.safe_dump({
            'purpose': purpose, 'camera': camera, 'solve_for': list(solve_for), 'fit_drift': fit_drift,
            'maneuvers': [maneuver_record(maneuver) for maneuver in maneuvers]}, sort_keys=False))))
        return fit_alignment(maneuvers, nominal_detector(camera), solve_for=solve_for, fit_drift=fit_drift,
                             initial_dcm=np.eye(3) if camera != 'hipo' else None)

    @property
    def _fit_drift(self):
        """Fit the residual drift (6.1) when every block has enough maneuvers to spare the unknowns."""
        return self.plan.repetitions >= _MIN_REPETITIONS_FOR_DRIFT_FIT

    def _imager_rotation_of_field(self):
        """Maneuver 4 of Table 3.4: EL/XEL rotations seen in each imager give A_XYIRF,TARF."""
        self._progress('rotation_of_field')
        self.record['imagers'] = {}
        updates = {}
        for camera in IMAGERS:
            maneuvers = yield from self._elxel_block(self.plan.verification_repetitions, camera)
            fit = self._fit(f'rotation_of_field_{camera}', maneuvers, solve_for=('los',), fit_drift=False,
                            camera=camera)
            updates[f'alignment.{camera}_from_tarf'] = fit.dcm.ravel().tolist()
            self.record['imagers'][camera] = {
                'rotation_of_field_arcsec': float(fit.angles_rad[2] * ARCSEC_PER_RAD),
                'sigma_arcsec': float(fit.sigma_rad[2] * ARCSEC_PER_RAD),
            }
        yield from self._push(updates)

    # --- boresights over elevation (Table 3.5, 6.2) ------------------------------------------
    def _reachable_star(self, target_deg, exclude):
        """Brightest catalogue star within 3 deg of an elevation that the fine drive reaches in azimuth."""
        utc = self.scenario.start_utc + dt.timedelta(seconds=self.stamp_ns / m.NS_PER_S)
        los_azimuth_deg = self.scenario.heading_deg - 90.0
        candidates = visible_stars(self.scenario.site, utc, WACO_2004_WEATHER, max_hp_magnitude=_SERIES_MAX_HP_MAG,
                                   min_altitude_deg=max(target_deg - 3.0, TELESCOPE_MIN_ELEVATION_DEG))
        for candidate in candidates:  # brightest first
            place = candidate.observed
            off_azimuth_deg = (place.azimuth_deg - los_azimuth_deg + 180.0) % 360.0 - 180.0
            reach_deg = abs(off_azimuth_deg) * np.cos(np.radians(place.altitude_deg))
            if (abs(place.altitude_deg - target_deg) <= 3.0 and reach_deg <= _SERIES_REACH_DEG
                    and candidate.star.hip not in exclude):
                return candidate.star
        return None

    def _flexure_row(self, name, hip, hp_magnitude):
        """Each imager's boresight against HIPO with the star held at HIPO's centre (6.2, Fig. 6.4)."""
        row = {'star': name, 'hip': int(hip), 'elevation_deg': self.joints[CD_JOINT] / RAD_PER_DEG}
        if hp_magnitude is not None:
            row['hp_mag'] = float(hp_magnitude)
        # As in 6.2: each imager against HIPO, so the star's residual offset in HIPO drops out.
        for camera in IMAGERS:
            hipo_px, _ = yield from self._star_frames('hipo', self.plan.frames_per_position)
            pixel, _ = yield from self._star_frames(camera, self.plan.frames_per_position)
            shift = (boresight_shift_arcsec(camera, pixel, self.record['boresight_px'][camera])
                     - boresight_shift_arcsec('hipo', hipo_px, nominal_detector('hipo').center_px))
            row[camera] = shift.tolist()
        return row

    def _flexure_series(self):
        """Boresights of the imagers against HIPO over elevation; fitted as in 3.28/3.29 about el0 (Table 3.5)."""
        self._progress('flexure_series')
        reference_hip = self.star_hip
        reference_elevation_deg = self.joints[CD_JOINT] / RAD_PER_DEG
        rows = [(yield from self._flexure_row('reference', reference_hip, None))]
        for target_deg in self.plan.flexure_elevations_deg:
            star = self._reachable_star(target_deg, exclude={row['hip'] for row in rows})
            if star is None:
                self._progress('flexure_point', {'elevation_deg': target_deg, 'skipped': 'no bright star in reach'})
                continue
            yield from self._point_at(star.hip)
            yield from self._acquire(star.hip)
            rows.append((yield from self._flexure_row(f'HIP {star.hip}', star.hip, star.hp_magnitude)))
            self._progress('flexure_point', {'star': rows[-1]['star'], 'elevation_deg': f'{rows[-1]["elevation_deg"]:.2f}'})
        # Differential flexure about el0: every row against the reference row, measured the same way.
        for row in rows[::-1]:
            for camera in IMAGERS:
                row[camera] = (np.asarray(row[camera]) - np.asarray(rows[0][camera])).tolist()
        self.record['flexure'] = {
            'reference_elevation_deg': reference_elevation_deg,
            'points': rows,
            'fit': {camera: flexure_fit(rows, camera, reference_elevation_deg) for camera in IMAGERS},
        }

    # --- the plan's elements (docs/plans.md) ------------------------------------------------
    def _fly_elements(self):
        """Each plan element in turn, recorded with its star, elevation and sim-time window."""
        flown = []
        for index, element in enumerate(self.plan.elements, 1):
            self._progress('element', {'index': index, 'kind': element.kind})
            start_s = self.stamp_ns / m.NS_PER_S
            record = yield from getattr(self, f'_fly_{element.kind}')(element)
            flown.append({'index': index, 'kind': element.kind, **record,
                          'start_s': start_s, 'end_s': self.stamp_ns / m.NS_PER_S})
        if flown:
            self.record['elements'] = flown

    def _near_elevation(self, target_deg):
        """The star centred in HIPO near ``target_deg`` (None: the current one); where, or why it was skipped."""
        here_deg = self.joints[CD_JOINT] / RAD_PER_DEG
        if target_deg is not None and abs(here_deg - target_deg) > _ELEVATION_TOLERANCE_DEG:
            star = self._reachable_star(target_deg, exclude=set())
            if star is None:
                self._progress('element_skipped', {'elevation_deg': target_deg}, DiagnosticStatus.WARN)
                return {'skipped': f'no star brighter than Hp {_SERIES_MAX_HP_MAG} within '
                                   f'{_ELEVATION_TOLERANCE_DEG:g} deg of {target_deg:g} deg in reach'}
            yield from self._point_at(star.hip)
            yield from self._acquire(star.hip)
        yield from self._centre_star()
        return {'hip': int(self.star_hip), 'elevation_deg': self.joints[CD_JOINT] / RAD_PER_DEG}

    def _turn_los_to(self, angle_deg):
        """Turn the fine drive's LOS to ``angle_deg`` about the centred star (not measured)."""
        fd_los_deg = self.joints.get(FD_JOINTS[2], 0.0) / RAD_PER_DEG
        yield from self._move(np.array([0.0, 0.0, (angle_deg - fd_los_deg) * RAD_PER_DEG]))

    def _fly_maneuvers(self, element):
        """Maneuvers 2 and 3 of Table 3.4 near another elevation, after a drift estimation there (6.1)."""
        place = yield from self._near_elevation(element.elevation_deg)
        if 'skipped' in place:
            return place
        repetitions = element.repetitions or self.plan.repetitions
        yield from self._estimate_drift()
        los = yield from self._los_block(repetitions)
        elxel = yield from self._elxel_block(repetitions)
        return {**place, 'los_maneuvers': len(los), 'elxel_maneuvers': len(elxel)}

    def _fly_los_rotations(self, element):
        """LOS rotations (maneuver 2) stepping through the element's fine-drive LOS angles about the centred star."""
        place = yield from self._near_elevation(element.elevation_deg)
        if 'skipped' in place:
            return place
        yield from self._turn_los_to(element.angles_deg[0])
        for before_deg, after_deg in zip(element.angles_deg, element.angles_deg[1:]):
            yield from self._maneuver('los', (after_deg - before_deg) * RAD_PER_DEG)
        return {**place, 'los_maneuvers': len(element.angles_deg) - 1}

    def _fly_hold(self, element):
        """The centred star held at the element's LOS angle (the Earth's turn walks it while the TASCU holds)."""
        place = yield from self._near_elevation(element.elevation_deg)
        if 'skipped' in place:
            return place
        yield from self._turn_los_to(element.los_deg)
        los_deg = self.joints.get(FD_JOINTS[2], 0.0) / RAD_PER_DEG
        hold_start_s, hold_end_s = yield from self._hold_for(element.duration_s)
        return {**place, 'los_deg': los_deg, 'hold_start_s': hold_start_s, 'hold_end_s': hold_end_s}

    def _fly_temperature(self, element):
        """A hold whose start commands the thermal setpoint: the temperature follows it while every camera records."""
        place = yield from self._near_elevation(element.elevation_deg)
        if 'skipped' in place:
            return place
        yield from self._turn_los_to(element.los_deg)
        los_deg = self.joints.get(FD_JOINTS[2], 0.0) / RAD_PER_DEG
        command = self._command_temperature(element.target_c, element.rate_c_per_h)
        hold_start_s, hold_end_s = yield from self._hold_for(element.duration_s)
        return {**place, 'los_deg': los_deg, **command, 'hold_start_s': hold_start_s, 'hold_end_s': hold_end_s}

    def result(self):
        """The accepted alignment and its predicted accuracy (3.32, 3.34, 3.37) as a plain mapping."""
        fit = self.final_fit
        los_count = self.record['iterations'][-1]['los_maneuvers']
        elxel_count = self.record['iterations'][-1]['elxel_maneuvers']
        sigma_c_rad = fit.sigma_c_px * nominal_detector('hipo').scale_rad_per_px
        sigma_r = sigma_r_rad(sigma_c_rad, self.plan.los_angle_deg * RAD_PER_DEG) / np.sqrt(los_count)
        sigma_beta = sigma_beta_from_length_rad(
            sigma_c_rad, self.plan.elxel_length_arcmin / 60.0 * RAD_PER_DEG) / np.sqrt(elxel_count)
        return {
            'accepted': True,
            'tarf_from_gyrf': np.asarray(self.active_alignment).tolist(),
            'predicted_sigma_arcsec': {'el': float(sigma_r * ARCSEC_PER_RAD), 'xel': float(sigma_r * ARCSEC_PER_RAD),
                                       'los': float(sigma_beta * ARCSEC_PER_RAD)},
            'plan': asdict(self.plan),
            **self.record,
        }
