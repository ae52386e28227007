"""Star-hop core: the observation sequence of 6.2-6.3 (Fig. 6.2, Tables D.3 and D.4).

Waco, 2004-09-02/03: six stars (Table 6.6) observed 17 times between 23 and 60 deg
elevation. For each observation the node waits for the table's time, turns the fine
drive's LOS back near zero (an inertial hold walks it at Earth rate), moves the telescope
with MTBS_INERTIAL (the coarse drive taking the elevation, 6.3) - or with MTBS_CENTROID when
the star is already in an imager - centres the star in the FFI and then HIPO, and holds it
for ``hold_s`` while every camera records frames (Table D.4: 112-315 s in 2004), then parks
the fine drive at zero XEL and LOS for the wait (the Earth would walk it into a stop). The TASCU
flies with the alignment matrix of eq. 6.1 unless the plan gives another: the star hop
measures a calibrated telescope.
"""

from __future__ import annotations

import datetime as dt
import warnings
from dataclasses import dataclass, field
from functools import cached_property
from typing import ClassVar

import numpy as np
import yaml
from diagnostic_msgs.msg import DiagnosticStatus

from sofia_ros import messages as m
from sofia_ros.calibration.published import EQ_6_1
from sofia_ros.errors import CalibrationAbort, InvalidArgumentError
from sofia_ros.graph_nodes import IMAGERS
from sofia_ros.plan_limits import MAX_OBSERVATION_OFFSET_S
from sofia_ros.sim.sequence import (
    TOPICS,
    SequenceCore,
    check_plan_limits,
    detector_offset,
    elements_from_yaml,
    elements_to_yaml,
    hold_duration,
    thermal_rate,
    thermal_target,
)
from sofia_ros.sky.catalogue import star_by_name
from sofia_ros.topics import CD_JOINT, FD_JOINTS
from sofia_ros.units import RAD_PER_DEG
from sofia_ros.validate import finite_array, orthonormal_dcm

__all__ = ['StarHopPlan', 'StarHopCore', 'StarHold', 'StarTemperatureHold', 'STAR_HOP_ELEMENTS',
           'TABLE_D3_OBSERVATIONS', 'CDT']

CDT = dt.timezone(dt.timedelta(hours=-5), 'CDT')
#: Table D.3: the star observed at each time (CDT), 2004-09-02/03.
TABLE_D3_OBSERVATIONS = (
    ('Eta Cep', '2004-09-02T23:22:16'), ('Polaris', '2004-09-02T23:32:51'), ('Eta Cep', '2004-09-02T23:43:38'),
    ('Polaris', '2004-09-02T23:47:13'), ('Alpha Cep', '2004-09-02T23:53:40'), ('Beta Cep', '2004-09-03T00:04:15'),
    ('Alpha Cep', '2004-09-03T00:08:23'), ('Polaris', '2004-09-03T00:14:30'), ('Beta Cep', '2004-09-03T00:17:36'),
    ('HIP 47193', '2004-09-03T00:25:03'), ('Beta Cep', '2004-09-03T00:28:39'), ('Polaris', '2004-09-03T00:33:01'),
    ('Beta Cep', '2004-09-03T00:37:26'), ('Xi Cep', '2004-09-03T00:44:26'), ('HIP 47193', '2004-09-03T00:50:59'),
    ('Polaris', '2004-09-03T00:53:50'), ('Xi Cep', '2004-09-03T00:57:03'),
)
_RECENTRE_LOS_DEG = 0.5


def table_d3_offsets_s():
    """(star, seconds after the first observation) of Table D.3."""
    times = [dt.datetime.fromisoformat(when).replace(tzinfo=CDT) for _, when in TABLE_D3_OBSERVATIONS]
    return tuple((star, (when - times[0]).total_seconds()) for (star, _), when in zip(TABLE_D3_OBSERVATIONS, times))


@dataclass(frozen=True)
class StarHold:
    """A catalogue star held for a while, at HIPO's centre or at a chosen position on a camera's detector."""

    kind: ClassVar[str] = 'hold'
    star: str
    duration_s: float
    #: the camera on whose detector the star is placed (None: held at HIPO's centre, as an observation)
    camera: str | None = None
    #: the star's offset from that detector's centre, arcsec along its x and y pixel axes
    detector_offset_arcsec: tuple | None = None

    def __post_init__(self):
        star_by_name(self.star)
        object.__setattr__(self, 'duration_s', hold_duration('duration_s', self.duration_s))
        if (self.camera is None) != (self.detector_offset_arcsec is None):
            raise InvalidArgumentError('a hold on a detector position needs both camera and detector_offset_arcsec')
        if self.camera is not None:
            object.__setattr__(self, 'detector_offset_arcsec', detector_offset(self.camera, self.detector_offset_arcsec))


@dataclass(frozen=True)
class StarTemperatureHold:
    """A catalogue star held at HIPO's centre while the truth's thermal control drives the temperature to a setpoint."""

    kind: ClassVar[str] = 'temperature'
    star: str
    #: the setpoint, deg C: within the truth's scenario.thermal_control range (checked with the truth)
    target_c: float
    duration_s: float
    #: how fast the setpoint moves from the temperature to target_c, deg C/h (None: the truth's largest, a plateau)
    rate_c_per_h: float | None = None

    def __post_init__(self):
        star_by_name(self.star)
        object.__setattr__(self, 'target_c', thermal_target('target_c', self.target_c))
        object.__setattr__(self, 'duration_s', hold_duration('duration_s', self.duration_s))
        object.__setattr__(self, 'rate_c_per_h', thermal_rate('rate_c_per_h', self.rate_c_per_h))


#: the star hop's plan elements by the name a plan file gives them
STAR_HOP_ELEMENTS = {element.kind: element for element in (StarHold, StarTemperatureHold)}


@dataclass(frozen=True)
class StarHopPlan:
    """The star-hop sequence: (star, start offset s) pairs, hold per star, timing and the TASCU's alignment."""

    #: the campaign this dataclass plans (its name in campaigns.registry)
    campaign: ClassVar[str] = 'star-hop'
    #: (star, seconds after Table D.3's first observation); the run starts at the first one listed.
    #: As node parameters: one array per column, plan.observations.star and plan.observations.offset_s.
    observations: tuple = field(default_factory=table_d3_offsets_s, metadata={'columns': ('star', 'offset_s')})
    hold_s: float = 60.0
    #: start each observation at its offset (Table D.3); False: as soon as the previous one is done
    follow_times: bool = True
    frames_per_position: int = 3
    timeout_s: float = 180.0
    tarf_from_gyrf: tuple = tuple(float(value) for value in EQ_6_1.ravel())
    #: the plan elements flown after the observations, back to back (STAR_HOP_ELEMENTS, docs/plans.md), as
    #: YAML text: one string, so that the plan still passes as node parameters (plan.elements_yaml)
    elements_yaml: str = ''

    def __post_init__(self):
        if len(self.observations) < 2:
            raise InvalidArgumentError('a star hop needs at least two observations')
        for star, offset_s in self.observations:
            star_by_name(star)
            if not 0.0 <= offset_s <= MAX_OBSERVATION_OFFSET_S:
                raise InvalidArgumentError(f'observation of {star} starts at {offset_s:g} s; offsets must be >= 0 and '
                                           f'<= {MAX_OBSERVATION_OFFSET_S:g} s (a night)')
        if self.hold_s <= 0:
            raise InvalidArgumentError(f'hold_s must be positive, got {self.hold_s}')
        check_plan_limits(self)
        matrix = finite_array('tarf_from_gyrf', self.tarf_from_gyrf, shape=(9,)).reshape(3, 3)
        with warnings.catch_warnings():
            warnings.simplefilter('ignore')  # eq. 6.1 is orthonormal to 1e-5 only; the TASCU takes it as printed
            orthonormal_dcm('tarf_from_gyrf', matrix)
        # Parsed now (a bad element is refused before the run) and kept in one spelling, so equal plans compare equal.
        object.__setattr__(self, 'elements_yaml',
                           elements_to_yaml(elements_from_yaml(self.elements_yaml, STAR_HOP_ELEMENTS, self.campaign)))

    @cached_property
    def elements(self):
        """The plan elements, parsed from ``elements_yaml``."""
        return elements_from_yaml(self.elements_yaml, STAR_HOP_ELEMENTS, self.campaign)


class StarHopCore(SequenceCore):
    """Commands the star-hop sequence and records each observation's hold window."""

    def __init__(self, plan, scenario):
        super().__init__(plan, scenario)
        self.record = {'observations': []}

    def _run(self):
        self._progress('acquire')
        yield from self._locked()
        yield from self._set_alignment(np.asarray(self.plan.tarf_from_gyrf).reshape(3, 3))
        for index, (star, offset_s) in enumerate(self.plan.observations):
            if self.plan.follow_times:
                # The run starts at the first planned observation (the scenario's start time).
                yield from self._until(offset_s - self.plan.observations[0][1])
            entry = star_by_name(star)
            yield from self._recentre_los(_RECENTRE_LOS_DEG)
            self._progress('observation', {'index': index + 1, 'star': star})
            if not (yield from self._centre_from_imager(entry.hip)):
                yield from self._point_at(entry.hip)
                yield from self._acquire(entry.hip)
            start_ns = self.stamp_ns
            yield from self._until(start_ns / m.NS_PER_S + self.plan.hold_s)
            self.record['observations'].append({
                'index': index + 1, 'star': star, 'hip': int(entry.hip),
                'hold_start_s': start_ns / m.NS_PER_S, 'hold_end_s': self.stamp_ns / m.NS_PER_S,
                'elevation_deg': self.joints[CD_JOINT] / RAD_PER_DEG,
            })
            yield from self._park()
        for index, element in enumerate(self.plan.elements, 1):
            self._progress('element', {'index': index, 'kind': element.kind, 'star': element.star})
            start_s = self.stamp_ns / m.NS_PER_S
            flown = yield from self._fly_within_reach(index, element)
            # The park that ends the element is part of its flight: the windows run back to back.
            yield from self._park()
            self.record.setdefault('elements', []).append(
                {'index': index, **flown, 'start_s': start_s, 'end_s': self.stamp_ns / m.NS_PER_S})
        self._progress('finished')
        self.outbox.append((TOPICS['result'].name, m.string_msg(yaml.safe_dump(
            {'accepted': True, 'campaign': 'star-hop', **self.record}, sort_keys=False))))

    def _fly_within_reach(self, index, element):
        """The element flown; skipped, with the TASCU's reason, where it refuses one of its commands.

        The Earth's turn walks the fine drive while a star is held (the aircraft has no azimuth drive), so whether a
        star or a placement on a detector is within the drives' travel is known only when it is commanded: the TASCU
        refuses such a command (the move is never flown), and the rest of the plan goes on.
        """
        try:
            return (yield from getattr(self, f'_fly_{element.kind}')(element))
        except CalibrationAbort:
            refusal = self._latest_refusal()
            if refusal is None:  # a timeout: the graph itself is at fault, not the element
                raise
        self._progress('element_skipped', {'index': index, 'kind': element.kind, 'star': element.star,
                                            'reason': refusal}, DiagnosticStatus.WARN)
        return {'kind': element.kind, 'star': element.star, 'skipped': f"out of the telescope's reach: {refusal}"}

    def _latest_refusal(self):
        """The TASCU's reason for refusing the latest command it answered; None if it did not refuse it."""
        if not self.command_status:
            return None
        answer = self.command_status[max(self.command_status)]
        return answer[len('refused: '):] if answer.startswith('refused: ') else None

    def _centre_element_star(self, element):
        """The element's star centred in HIPO (from an imager that shows it, else pointed at); its record."""
        entry = star_by_name(element.star)
        yield from self._recentre_los(_RECENTRE_LOS_DEG)
        if not (yield from self._centre_from_imager(entry.hip)):
            yield from self._point_at(entry.hip)
            yield from self._acquire(entry.hip)
        return {'kind': element.kind, 'star': element.star, 'hip': int(entry.hip)}

    def _fly_hold(self, element):
        """A hold element: the star centred in HIPO, placed on the detector position if one is asked, held."""
        record = yield from self._centre_element_star(element)
        if element.camera is not None:
            pixel = yield from self._place_on_detector(element.camera, element.detector_offset_arcsec)
            record.update(camera=element.camera, pixel=[float(pixel[0]), float(pixel[1])])
        hold_start_s, hold_end_s = yield from self._hold_for(element.duration_s)
        return {**record, 'hold_start_s': hold_start_s, 'hold_end_s': hold_end_s,
                'elevation_deg': self.joints[CD_JOINT] / RAD_PER_DEG}

    def _fly_temperature(self, element):
        """A temperature element: the star centred in HIPO and held from the thermal command on."""
        record = yield from self._centre_element_star(element)
        record.update(self._command_temperature(element.target_c, element.rate_c_per_h))
        hold_start_s, hold_end_s = yield from self._hold_for(element.duration_s)
        return {**record, 'hold_start_s': hold_start_s, 'hold_end_s': hold_end_s,
                'elevation_deg': self.joints[CD_JOINT] / RAD_PER_DEG}

    def _park(self):
        """Turn the fine drive's XEL and LOS back to zero: waiting on a star, the Earth walks them to the stops."""
        fine_drive = np.array([self.joints.get(joint, 0.0) for joint in FD_JOINTS])
        yield from self._move(np.array([0.0, -fine_drive[1], -fine_drive[2]]))

    def _centre_from_imager(self, hip):
        """MTBS_CENTROID from the widest imager that already shows the star (6.3); False if none does."""
        for camera in reversed(IMAGERS):
            frames = self.frames[camera]
            latest = frames[-1][1] if frames else ()
            pixel = next(((x, y) for star_hip, x, y in latest if star_hip == hip), None)
            if pixel is not None:
                self.star_hip = hip
                yield from self._command('mtbs_centroid', self._point_message(camera, pixel))
                yield from self._locked()
                yield from self._acquire(hip)
                return True
        return False
