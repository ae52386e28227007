"""Gyro stability campaigns TC-1 to TC-4 (5.2): the telescope stationary in the hangar at Edwards.

CD at 40.1077 deg, true heading 324 deg (GPS), N 34.9368 deg, 697 m (Table 5.3, 5.2.1). The
plant holds the telescope to the Earth (the gyros see eqs. 4.1-4.3); the truth file gives the
gyros' own errors and the case adds the disturbances its subsystem configuration brings
(Table 5.2; lines of 5.2.5 and Tables 5.4/5.5). Line amplitudes are illustrative: the thesis
shows them only as PSD plots (Figs. 5.10-5.12). The case's subsystem configuration (Table 5.2:
RIS, FD, CD, VIS, oil pumps, cooling carts, fans) is recorded as a latched DiagnosticStatus on
/ta/subsystem_status, for `sofia noise` and any ROS tool.
"""

from __future__ import annotations

import datetime as dt
import time
from dataclasses import dataclass

import yaml

from sofia_ros import interrupts
from sofia_ros import messages as m
from sofia_ros.bag.timebase import epoch_ns_of
from sofia_ros.campaigns.recording import finish_run, new_bag_path, write_summary
from sofia_ros.effects import resolve_params
from sofia_ros.errors import ConfigError, OutputError
from sofia_ros.scenario import Scenario, scenario_document
from sofia_ros.sim.clock import ClockCore
from sofia_ros.sim.gyro_box import GyroBoxCore
from sofia_ros.sim.plant import PlantCore
from sofia_ros.sim.runner import LockstepRunner
from sofia_ros.sky import EDWARDS_2007_SITE
from sofia_ros.topics import CASE_DOCUMENT, DEFAULT_TICK_NS, SCENARIO_DOCUMENT, SUBSYSTEM_STATUS, TRUTH_DOCUMENT
from sofia_ros.units import GYRO_SAMPLE_RATE_HZ

__all__ = ['TestCase', 'CASES', 'edwards_scenario', 'case_effects', 'run_gyro_stability']

#: 2007-06-21, the first day of the test series (5.2); the hour is arbitrary (gyros do not see the sky).
START_UTC = dt.datetime(2007, 6, 21, 18, 0, 0, tzinfo=dt.timezone.utc)


@dataclass(frozen=True)
class TestCase:
    """One configuration of Table 5.2 as run in 5.2.1."""

    name: str
    description: str
    default_hours: float
    #: (frequency Hz, amplitude arcsec/s, axis) lines the configuration excites
    lines: tuple
    los_oscillation_period_s: float | None
    #: (subsystem, state) of Table 5.2 and 5.2.1, recorded on topics.SUBSYSTEM_STATUS
    subsystems: tuple


_ALWAYS = ((0.7, 0.05, 'el'), (0.7, 0.02, 'xel'), (1.3, 0.05, 'el'), (1.3, 0.02, 'los'))
_TC1_SERIES = tuple((10.0 + 3.3 * k, 0.02, axis) for k in range(0, 28, 3) for axis in ('el', 'xel'))
_OIL_PUMP = ((30.0, 0.15, 'el'), (30.0, 0.1, 'xel'), (30.0, 0.1, 'los'), (190.2, 0.1, 'el'), (190.2, 0.1, 'xel'))

def _subsystems(ris, fd, fd_control, vis):
    """Table 5.2 states of one case; oil pumps and cooling carts run exactly when the RIS does (5.2.1, 5.2.2)."""
    floated = ris == 'activated'
    return (('ris', ris), ('fd', fd), ('fd_control', fd_control), ('cd', 'held at 40.1077 deg'), ('vis', vis),
            ('main_oil_pump', 'on, high rate' if floated else 'off'),
            ('return_pumps', 'activated periodically' if floated else 'off'),
            ('cooling_carts', 'on (TA oil cooling)' if floated else 'off'), ('aircraft_fans', 'off'))


_CAGED, _UNCAGED = 'caged', 'uncaged (axial air springs evacuated)'
CASES = {
    'TC-1': TestCase('TC-1', 'RIS shut down, telescope not floated, VIS caged', 4.0,
                     _ALWAYS + _TC1_SERIES + ((179.1, 0.2, 'el'), (179.1, 0.2, 'xel')), 1200.0,
                     _subsystems('deactivated', 'braked', 'off', _CAGED)),
    'TC-2': TestCase('TC-2', 'RIS active (floated), FD braked, VIS caged', 4.0,
                     _ALWAYS + _OIL_PUMP + ((11.7, 0.05, 'el'),), 2400.0,
                     _subsystems('activated', 'braked', 'off', _CAGED)),
    'TC-3': TestCase('TC-3', 'RIS active, FD braked, VIS uncaged', 4.0,
                     _ALWAYS + _OIL_PUMP + ((2.3, 0.08, 'xel'), (2.3, 0.08, 'los')), None,
                     _subsystems('activated', 'braked', 'off', _UNCAGED)),
    'TC-4': TestCase('TC-4', 'RIS active, FD open loop, VIS uncaged', 25.0 / 60.0,
                     _ALWAYS + ((30.0, 0.05, 'el'), (1.0, 0.08, 'el'), (3.4, 0.1, 'el')), 1200.0,
                     _subsystems('activated', 'unbraked', 'open loop, TA balanced', _UNCAGED)),
}
#: The case's TA configuration (Table 5.2) as one latched diagnostic_msgs/DiagnosticStatus.


def edwards_scenario():
    """Table 5.3: Edwards AFB hangar, heading 324 deg, CD 40.1077 deg."""
    return Scenario(EDWARDS_2007_SITE, START_UTC, 324.0, 40.1077)


def case_effects(case, truth_effects):
    """The truth's effects plus the case's lines and LOS oscillation (unless the truth sets them)."""
    effects = dict(truth_effects)
    effects.setdefault('earth_rotation', resolve_params('earth_rotation', {}))
    if 'vibration_lines' not in effects:
        frequencies, amplitudes, axes = zip(*case.lines)
        effects['vibration_lines'] = {'frequencies_hz': list(frequencies),
                                      'amplitudes_arcsec_per_s': list(amplitudes), 'axes': list(axes)}
    if case.los_oscillation_period_s and 'los_oscillation' not in effects:
        effects['los_oscillation'] = {**resolve_params('los_oscillation', {}),
                                      'period_s': case.los_oscillation_period_s}
    return effects


def run_gyro_stability(truth, *, case, hours, seed, bag_path, progress=None):
    """Run one case in the lock-step runner (plant braked to the Earth, 400 Hz gyro box), bag recorded."""
    if case not in CASES:
        raise ConfigError(f'case must be one of {", ".join(CASES)}, got {case!r}')
    test_case = CASES[case]
    hours = test_case.default_hours if hours is None else float(hours)
    if not 0.0 < hours <= 24.0:
        raise ConfigError(f'--hours must be in (0, 24], got {hours:g}')
    bag_path = new_bag_path(bag_path)
    effects = case_effects(test_case, truth.effects)
    scenario = edwards_scenario()
    cores = [ClockCore(), PlantCore(scenario, effects, fd_braked=True, tick_ns=DEFAULT_TICK_NS),
             GyroBoxCore(effects, seed=seed)]
    case_text = yaml.safe_dump({'case': case, 'description': test_case.description, 'hours': hours,
                                'heading_deg': scenario.heading_deg, 'elevation_deg': scenario.start_elevation_deg,
                                'latitude_deg': scenario.latitude_deg, 'effects': effects}, sort_keys=False)
    wall_start = time.perf_counter()
    from sofia_ros.bag import BagWriter  # here: node processes import this module, and need no bag writer

    bag = BagWriter(bag_path, epoch_ns=epoch_ns_of(scenario.start_utc))
    bag.open()
    runner = LockstepRunner(cores, tick_ns=DEFAULT_TICK_NS, bag=bag)
    try:
        with interrupts.graceful():
            bag.write_document(TRUTH_DOCUMENT.name, truth.text, 0)
            bag.write_document(CASE_DOCUMENT.name, case_text, 0)
            bag.write_document(SCENARIO_DOCUMENT.name, scenario_document(scenario), 0)
            bag.add_topic(SUBSYSTEM_STATUS.name, SUBSYSTEM_STATUS.msgtype, latched=True)
            bag.write_message(SUBSYSTEM_STATUS.name, m.status_msg('ta_subsystems', f'{case}: {test_case.description}',
                                                                  dict(test_case.subsystems), hardware_id='TA'), 0)
            until_ns = int(round(hours * 3600.0 * 1e9))

            def stop():
                if progress is not None:
                    progress(runner.stamp_ns / 1e9, hours * 3600.0)
                return interrupts.requested() is not None

            runner.run(until_ns=until_ns, stop=stop)
        bag.close()  # here, not only in finally: a disk that fills up as the bag is finished is a fault too
    except OutputError as err:
        # The disk filled up: the bag keeps what reached it (BagWriter says how much); a fault, exit 3.
        finish_run(bag_path, {'case': case, 'sim_seconds': round(runner.stamp_ns / 1e9, 3),
                              'wall_seconds': round(time.perf_counter() - wall_start, 3)}, str(err))
    except Exception as err:
        # A bug: close what was recorded, keep the reason in summary.json; the traceback follows.
        bag.close()
        try:
            write_summary(bag_path, {'case': case, 'sim_seconds': round(runner.stamp_ns / 1e9, 3), 'stopped': 'fault',
                                     'reason': f'{type(err).__name__}: {err}'})
        except OutputError:
            pass  # a full disk too: the bug's traceback, which follows, matters more
        raise
    finally:
        bag.close()
    sim_seconds = runner.stamp_ns / 1e9
    summary = {'case': case, 'sim_seconds': round(sim_seconds, 3),
               'wall_seconds': round(time.perf_counter() - wall_start, 3),
               'samples_per_axis': int(round(sim_seconds * GYRO_SAMPLE_RATE_HZ))}
    finish_run(bag_path, summary, side_files={'truth.yaml': truth.text, 'case.yaml': case_text})
    return summary
