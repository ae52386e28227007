"""The alignment campaign: Table 3.4 at the reference elevation on Polaris, Waco 2004-09-03 (6.1)."""

from __future__ import annotations

import dataclasses
import datetime as dt
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml

from sofia_ros.campaigns.plan_files import check_plan_with_truth
from sofia_ros.campaigns.recording import MODES, finish_run, new_bag_path, record_campaign
from sofia_ros.frames import AXES
from sofia_ros.mount import check_coarse_drive_elevation
from sofia_ros.rotation_kernels import rotvec_from_matrix
from sofia_ros.scenario import Scenario, scenario_from_mapping
from sofia_ros.sensors.gyro_errors import tarf_from_gyrf_dcm
from sofia_ros.sensors.imager_model import camera_errors, camera_from_tarf_dcm
from sofia_ros.sim.calibration import AlignmentPlan
from sofia_ros.sim.graph import DEFAULT_MAX_SIM_S, GraphConfig
from sofia_ros.sim.sequence import PLAN_FILE_NAME, elements_budget_s, plan_text
from sofia_ros.sky import TELESCOPE_MIN_ELEVATION_DEG, WACO_2004_SITE, WACO_2004_WEATHER, observed_place
from sofia_ros.topics import CALIBRATION_RESULT, CLOCK, STOP_DOCUMENT
from sofia_ros.units import ARCSEC_PER_RAD

__all__ = ['MODES', 'AlignmentRun', 'default_scenario', 'graph_config', 'run_alignment',
           'residual_misalignment_arcsec', 'true_alignment_at']

#: Observation 2 of Table D.3: Polaris, 2004-09-02 23:32:51 CDT.
DEFAULT_START_UTC = dt.datetime(2004, 9, 3, 4, 32, 51, tzinfo=dt.timezone.utc)
TARGET_STAR = 'Polaris'


@dataclass(frozen=True)
class AlignmentRun:
    """What a finished run reports (summary.json, docs/cli.md)."""

    summary: dict
    result_yaml: str
    bag_path: Path | None


def pointing_at_target(site, start_utc):
    """Heading and CD elevation that put the target star on the LOS (6.1); refuses stars below 20 deg."""
    place = observed_place(TARGET_STAR, site, start_utc, WACO_2004_WEATHER, min_altitude_deg=TELESCOPE_MIN_ELEVATION_DEG)
    # The telescope looks out of the left side: azimuth = heading - 90 deg (C.3.2).
    return 90.0 + place.azimuth_deg, place.apparent_altitude_deg


def default_scenario():
    """Waco 2004: the aircraft heading and CD elevation put Polaris on the LOS at the start (6.1)."""
    heading_deg, elevation_deg = pointing_at_target(WACO_2004_SITE, DEFAULT_START_UTC)
    return Scenario(WACO_2004_SITE, DEFAULT_START_UTC, heading_deg, elevation_deg)


def graph_config(truth, seed, plan=None):
    """The alignment campaign's GraphConfig: the truth's scenario over the Waco default.

    A truth that moves the site or the time without giving heading and elevation gets
    the pointing recomputed for the target star there and then. A temperature element the
    truth cannot fly is refused here, before the run.
    """
    overrides = dict(truth.scenario or {})
    scenario = scenario_from_mapping(default_scenario(), overrides)
    if overrides and not {'heading_deg', 'start_elevation_deg'} & set(overrides):
        heading_deg, elevation_deg = pointing_at_target(scenario.site, scenario.start_utc)
        scenario = dataclasses.replace(scenario, heading_deg=heading_deg, start_elevation_deg=elevation_deg)
    check_coarse_drive_elevation(scenario.start_elevation_deg)
    plan = plan or AlignmentPlan()
    check_plan_with_truth(plan, scenario, truth.source)
    return GraphConfig(truth, scenario, seed, plan)


def true_alignment_at(truth_effects, elevation_deg):
    """A_TARF,GYRF that aligns the gyros to HIPO's true focal plane at one elevation (3.4.2).

    The alignment measured at el0 contains the focal-plane flexure at el0: the target is
    the true gyro misalignment seen through HIPO's true mounting (gravity image motion).
    """
    hipo_from_tarf = camera_from_tarf_dcm(camera_errors('hipo', truth_effects), elevation_deg)
    return hipo_from_tarf @ tarf_from_gyrf_dcm(truth_effects)


def residual_misalignment_arcsec(accepted_tarf_from_gyrf, truth_effects, elevation_deg):
    """Accepted minus true alignment (at the campaign elevation) as rotations about EL, XEL, LOS, arcsec."""
    error = np.asarray(accepted_tarf_from_gyrf) @ true_alignment_at(truth_effects, elevation_deg).T
    return rotvec_from_matrix(error.T) * ARCSEC_PER_RAD


def run_alignment(truth, *, seed, bag_path, plan=None, mode='executor', max_sim_s=None,
                  model_text='effects: {}\n', progress=None, timeout_s=3600.0):
    """Run the campaign and write the bag plus truth.yaml, model.yaml, plan.yaml, calibration.yaml and summary.json.

    ``mode``: one of recording.MODES ('direct' for Monte Carlo and fast tests). ``max_sim_s``: the sim-time
    cap (default: DEFAULT_MAX_SIM_S and an allowance for the plan's elements).
    """
    bag_path = new_bag_path(bag_path)
    config = graph_config(truth, seed, plan)
    if max_sim_s is None:
        max_sim_s = DEFAULT_MAX_SIM_S + elements_budget_s(config.plan.elements, config.plan.timeout_s)
    wall_start = time.perf_counter()
    fault = record_campaign(config, bag_path, model_text=model_text, mode=mode, max_sim_s=max_sim_s,
                            timeout_s=timeout_s, progress=progress)
    wall_seconds = time.perf_counter() - wall_start
    result_yaml, sim_seconds = result_from_bag(bag_path)
    result = yaml.safe_load(result_yaml)
    if result.get('reason') == NO_RESULT and sim_seconds >= max_sim_s - config.tick_ns / 1e9:
        result['reason'] = (f'the run reached its sim-time limit (--max-sim-s {max_sim_s:g}) before the calibration '
                            'finished; give a larger --max-sim-s')
        result_yaml = yaml.safe_dump(result)
    summary = _summary(result, truth, config.scenario.start_elevation_deg, sim_seconds,
                       wall_seconds)
    finish_run(bag_path, summary, fault,
               side_files={'truth.yaml': truth.text, 'model.yaml': model_text, PLAN_FILE_NAME: plan_text(config.plan),
                           'calibration.yaml': result_yaml})
    return AlignmentRun(summary, result_yaml, bag_path)


#: Why an alignment was not accepted when the bag holds no calibration result and no stop reason.
NO_RESULT = 'the calibration node published no result'


def result_from_bag(bag_path):
    """The calibration node's last /calibration/result and the last /clock time (s since the start), from the bag."""
    from sofia_ros.bag import BagReader  # here: node processes import this module, and need no bag reader

    with BagReader(bag_path, campaign_time=True) as bag:
        names = {topic.name for topic in bag.topics}
        # The clock's last log time from the message indexes and the one chunk that holds it, not every tick's.
        sim_ns = bag.last_log_time_ns(CLOCK.name) or 0
        results = (bag.messages_by_topic(CALIBRATION_RESULT.name)[CALIBRATION_RESULT.name][1]
                   if CALIBRATION_RESULT.name in names else ())
        result = results[-1].data if len(results) else None
        stop_reason = bag.document(STOP_DOCUMENT.name) if STOP_DOCUMENT.name in names else None
    if result is None:
        reason = f'stopped: {stop_reason}' if stop_reason else NO_RESULT
        result = yaml.safe_dump({'accepted': False, 'reason': reason})
    return result, sim_ns / 1e9


def _elements_summary(elements):
    """How many plan elements were flown and why any was skipped (no star in reach at its elevation)."""
    skipped = [f'element {element["index"]} ({element["kind"]}): {element["skipped"]}'
               for element in elements if 'skipped' in element]
    return {'flown': len(elements) - len(skipped), 'skipped': skipped}


def _summary(result, truth, elevation_deg, sim_seconds, wall_seconds):
    summary = {'sim_seconds': round(sim_seconds, 3), 'wall_seconds': round(wall_seconds, 3),
               'accepted': bool(result.get('accepted'))}
    if summary['accepted']:
        residual = residual_misalignment_arcsec(result['tarf_from_gyrf'], truth.effects, elevation_deg)
        summary['residual_misalignment_arcsec'] = dict(zip(AXES, (float(v) for v in residual)))
        summary['predicted_sigma_arcsec'] = result['predicted_sigma_arcsec']
        summary['iterations'] = len(result['iterations'])
        if 'elements' in result:
            summary['elements'] = _elements_summary(result['elements'])
    else:
        summary['reason'] = result.get('reason', 'not finished')
    return summary
