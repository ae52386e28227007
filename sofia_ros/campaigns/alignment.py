"""The alignment campaign: Table 3.4 at the reference elevation on Polaris, Waco 2004-09-03 (6.1)."""

from __future__ import annotations

import datetime as dt
import json
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from sofia_ros.bag import BagWriter
from sofia_ros.errors import ConfigError
from sofia_ros.sim.calibration import AlignmentPlan
from sofia_ros.sim.graph import GraphConfig, build_cores
from sofia_ros.sim.gyro_box import true_tarf_from_gyrf
from sofia_ros.sim.runner import LockstepRunner
from sofia_ros.sim.scenario import Scenario, scenario_from_mapping
from sofia_ros.sky import WACO_2004_SITE, WACO_2004_WEATHER, observed_place
from sofia_ros.units import ARCSEC_PER_RAD

__all__ = ['AlignmentRun', 'default_scenario', 'graph_config', 'run_alignment', 'residual_misalignment_arcsec']

#: Observation 2 of Table D.3: Polaris, 2004-09-02 23:32:51 CDT.
DEFAULT_START_UTC = dt.datetime(2004, 9, 3, 4, 32, 51, tzinfo=dt.timezone.utc)
TARGET_STAR = 'Polaris'


@dataclass(frozen=True)
class AlignmentRun:
    """What a finished run reports (summary.json, DESIGN.md section 6)."""

    summary: dict
    result_yaml: str
    bag_path: Path | None


def default_scenario():
    """Waco 2004: the aircraft heading and CD elevation put Polaris on the LOS at the start (6.1)."""
    place = observed_place(TARGET_STAR, WACO_2004_SITE, DEFAULT_START_UTC, WACO_2004_WEATHER)
    # The telescope looks out of the left side: azimuth = heading - 90 deg (C.3.2).
    return Scenario(WACO_2004_SITE, DEFAULT_START_UTC, 90.0 + place.azimuth_deg, place.apparent_altitude_deg)


def graph_config(truth, seed, plan=None):
    """The alignment campaign's GraphConfig: the truth's scenario over the Waco default."""
    return GraphConfig(truth, scenario_from_mapping(default_scenario(), truth.scenario), seed, plan or AlignmentPlan())


def residual_misalignment_arcsec(accepted_tarf_from_gyrf, truth_effects):
    """Accepted minus true alignment as small rotations about the TARF axes (EL, XEL, LOS), arcsec."""
    error = np.asarray(accepted_tarf_from_gyrf) @ true_tarf_from_gyrf(truth_effects).T
    return Rotation.from_matrix(error.T).as_rotvec() * ARCSEC_PER_RAD


def run_alignment(truth, *, seed, bag_path=None, plan=None, max_sim_s=7200.0, model_text='effects: {}\n',
                  progress=None):
    """Run the campaign in one process (lock-step runner) and return its summary."""
    config = graph_config(truth, seed, plan)
    cores = build_cores(config)
    calibration = cores[-1]
    bag = BagWriter(bag_path) if bag_path is not None else None
    wall_start = time.perf_counter()
    try:
        if bag is not None:
            bag.open()
            bag.write_document('/config/truth', truth.text, 0)
            bag.write_document('/config/model', model_text, 0)
        runner = LockstepRunner(cores, tick_ns=config.tick_ns, bag=bag)
        until_ns = int(max_sim_s * 1e9)

        def stop():
            if progress is not None:
                progress(runner.stamp_ns / 1e9, max_sim_s)
            return calibration.outcome.finished or calibration.outcome.failed

        runner.run(until_ns=until_ns, stop=stop)
        result_yaml = _result_yaml(calibration, runner.stamp_ns >= until_ns, max_sim_s)
        summary = _summary(calibration, truth, runner.stamp_ns / 1e9, time.perf_counter() - wall_start)
        if bag is not None:
            bag.write_document('/result/calibration', result_yaml, runner.stamp_ns)
            bag.write_document('/result/summary', json.dumps(summary, indent=2), runner.stamp_ns)
            bag.close()
    except BaseException:
        if bag is not None:
            bag.abort()
        raise
    if bag_path is not None:
        folder = Path(bag_path)
        (folder / 'truth.yaml').write_text(truth.text)
        (folder / 'model.yaml').write_text(model_text)
        (folder / 'calibration.yaml').write_text(result_yaml)
        (folder / 'summary.json').write_text(json.dumps(summary, indent=2) + '\n')
    return AlignmentRun(summary, result_yaml, Path(bag_path) if bag_path is not None else None)


def _result_yaml(calibration, timed_out, max_sim_s):
    import yaml

    if calibration.outcome.finished:
        return yaml.safe_dump(calibration.result(), sort_keys=False)
    reason = calibration.outcome.reason or (f'not finished within {max_sim_s:g} s of sim time' if timed_out else '')
    return yaml.safe_dump({'accepted': False, 'reason': reason}, sort_keys=False)


def _summary(calibration, truth, sim_seconds, wall_seconds):
    summary = {'sim_seconds': round(sim_seconds, 3), 'wall_seconds': round(wall_seconds, 3),
               'accepted': bool(calibration.outcome.finished)}
    if calibration.outcome.finished:
        result = calibration.result()
        residual = residual_misalignment_arcsec(result['tarf_from_gyrf'], truth.effects)
        summary['residual_misalignment_arcsec'] = dict(zip(('el', 'xel', 'los'), (float(v) for v in residual)))
        summary['predicted_sigma_arcsec'] = result['predicted_sigma_arcsec']
        summary['iterations'] = len(result['iterations'])
    else:
        summary['reason'] = calibration.outcome.reason or 'not finished'
    return summary


def check_truth_for_alignment(truth):
    """Refuse truths the campaign cannot run (e.g. no stars without the sky)."""
    if 'earth_rotation' not in truth.effects:
        raise ConfigError('alignment truth lacks earth_rotation; add `earth_rotation: {}` (the sky turns)')
