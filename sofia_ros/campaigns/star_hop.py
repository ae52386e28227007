"""The star-hop campaign: absolute pointing (6.3) and differential flexure (6.2), Waco 2004-09-02/03.

The node graph flies Table D.3's 17 observations of six stars (sim.star_hop); the bag then
holds every centroid, the 400 Hz gyro samples and each observation's hold window, which
`analysis.star_hop` turns into Table 6.7 and Fig. 6.11 and `sofia compare` into ranked effects.
"""

from __future__ import annotations

import datetime as dt
import time

import yaml

from sofia_ros.campaigns.alignment import result_from_bag
from sofia_ros.campaigns.plan_files import check_plan_with_truth
from sofia_ros.campaigns.recording import finish_run, new_bag_path, record_campaign
from sofia_ros.mount import check_coarse_drive_elevation
from sofia_ros.scenario import Scenario, scenario_from_mapping
from sofia_ros.sim.graph import GraphConfig
from sofia_ros.sim.sequence import PLAN_FILE_NAME, elements_budget_s, plan_text
from sofia_ros.sim.star_hop import CDT, TABLE_D3_OBSERVATIONS, StarHopPlan
from sofia_ros.sky import TELESCOPE_MIN_ELEVATION_DEG, WACO_2004_SITE, WACO_2004_WEATHER, observed_place

__all__ = ['default_scenario', 'run_star_hop', 'star_hop_config']


def default_scenario(first_star=TABLE_D3_OBSERVATIONS[0][0], offset_s=0.0):
    """Waco at the first planned observation (Table D.3 start + offset), that star on the LOS (C.3.2).

    The aircraft stood still that night: its heading is the one that put Table D.3's first star,
    Eta Cep, on the LOS at 23:22:16 CDT, whichever slice of the table is flown.
    """
    table_start = dt.datetime.fromisoformat(TABLE_D3_OBSERVATIONS[0][1]).replace(tzinfo=CDT)
    start_utc = (table_start + dt.timedelta(seconds=offset_s)).astimezone(dt.timezone.utc)
    parked = observed_place(TABLE_D3_OBSERVATIONS[0][0], WACO_2004_SITE, table_start.astimezone(dt.timezone.utc),
                            WACO_2004_WEATHER, min_altitude_deg=TELESCOPE_MIN_ELEVATION_DEG)
    place = observed_place(first_star, WACO_2004_SITE, start_utc, WACO_2004_WEATHER,
                           min_altitude_deg=TELESCOPE_MIN_ELEVATION_DEG)
    return Scenario(WACO_2004_SITE, start_utc, 90.0 + parked.azimuth_deg, place.apparent_altitude_deg)


def star_hop_config(truth, seed, plan=None):
    """The star hop's GraphConfig: the truth's scenario over the Waco default; a temperature element the truth
    cannot fly is refused here, before the run."""
    plan = plan or StarHopPlan()
    scenario = scenario_from_mapping(default_scenario(*plan.observations[0]), truth.scenario)
    check_coarse_drive_elevation(scenario.start_elevation_deg)
    check_plan_with_truth(plan, scenario, truth.source)
    return GraphConfig(truth, scenario, seed, plan)


def run_star_hop(truth, *, seed, bag_path, plan=None, mode='executor', model_text='effects: {}\n', progress=None,
                 timeout_s=3600.0):
    """Fly the sequence, record the bag, and write truth.yaml, model.yaml, plan.yaml, star_hop.yaml and summary.json.

    ``mode``: one of recording.MODES, as for the alignment campaign.
    """
    bag_path = new_bag_path(bag_path)
    config = star_hop_config(truth, seed, plan)
    last_offset_s = config.plan.observations[-1][1]
    max_sim_s = (last_offset_s - config.plan.observations[0][1] + 20.0 * config.plan.timeout_s + config.plan.hold_s
                 + elements_budget_s(config.plan.elements, config.plan.timeout_s))
    wall_start = time.perf_counter()
    fault = record_campaign(config, bag_path, model_text=model_text, mode=mode, max_sim_s=max_sim_s,
                            timeout_s=timeout_s, progress=progress)
    wall_seconds = time.perf_counter() - wall_start
    result_yaml, sim_seconds = result_from_bag(bag_path)
    result = yaml.safe_load(result_yaml)
    elements = result.get('elements', [])
    skipped = [f'element {element["index"]} ({element["kind"]}): {element["skipped"]}'
               for element in elements if 'skipped' in element]
    summary = {'sim_seconds': round(sim_seconds, 3), 'wall_seconds': round(wall_seconds, 3),
               'finished': bool(result.get('accepted')), 'observations': len(result.get('observations', [])),
               'elements': len(elements) - len(skipped), 'elements_skipped': skipped}
    if not summary['finished']:
        summary['reason'] = result.get('reason', 'not finished')
    finish_run(bag_path, summary, fault,
               side_files={'truth.yaml': truth.text, 'model.yaml': model_text, PLAN_FILE_NAME: plan_text(config.plan),
                           'star_hop.yaml': result_yaml})
    return summary
