"""Star-hop plan elements (docs/plans.md): one out of the telescope's reach is skipped and the run goes on; every
element records its sim-time window."""

import re
from pathlib import Path

import numpy as np
import pytest
import yaml
from diagnostic_msgs.msg import DiagnosticStatus

from sofia_ros import messages as m
from sofia_ros.bag import BagReader
from sofia_ros.campaigns.star_hop import run_star_hop
from sofia_ros.config import load_effect_config
from sofia_ros.errors import CalibrationAbort
from sofia_ros.sim.star_hop import StarHopCore, StarHopPlan
from sofia_ros.topics import CALIBRATION_PROGRESS, FD_JOINTS, JOINT_STATES

ROOT = Path(__file__).resolve().parents[1]
NOMINAL = ROOT / 'config' / 'truth' / 'nominal.yaml'
THERMAL = ROOT / 'config' / 'truth' / 'nominal-thermal.yaml'
# Alpha Cep 480 s after Table D.3's first observation sits near +2.9 deg of the fine drive's XEL (the aircraft has no
# azimuth drive): 1250" along the FFI's -x asks for +3.06 deg, which the TASCU refuses; the hold at HIPO's centre after
# it is in reach. Held 2 s each: about 210 s of sim, 6-10 s of wall.
OUT_OF_REACH = ('[{hold: {star: Alpha Cep, duration_s: 2, camera: ffi, detector_offset_arcsec: [-1250, 0]}}, '
                '{hold: {star: Alpha Cep, duration_s: 2}}]')
PLAN = StarHopPlan(observations=(('Alpha Cep', 480.0), ('Alpha Cep', 490.0)), hold_s=2.0, follow_times=False,
                   elements_yaml=OUT_OF_REACH)
REFUSAL = r"out of the telescope's reach: fine drive XEL would reach \+3\.\d{3} deg, beyond the \+-3 deg travel"


@pytest.fixture(scope='module')
def flown(tmp_path_factory):
    """(summary, star_hop.yaml, bag) of the reduced star hop whose placed hold is out of the fine drive's travel."""
    bag = tmp_path_factory.mktemp('star-hop') / 'bag'
    summary = run_star_hop(load_effect_config(NOMINAL), seed=2, bag_path=bag, plan=PLAN, mode='direct')
    return summary, yaml.safe_load((bag / 'star_hop.yaml').read_text()), bag


def test_a_placement_beyond_the_fine_drives_travel_is_skipped_and_the_star_hop_finishes(flown):
    summary, result, bag = flown
    assert summary['finished'] and result['accepted']
    skipped, held = result['elements']
    assert re.fullmatch(r'element 1 \(hold\): ' + REFUSAL + '.*', *summary['elements_skipped'])
    assert summary['elements'] == 1
    assert (skipped['kind'], skipped['star']) == ('hold', 'Alpha Cep') and re.match(REFUSAL, skipped['skipped'])
    assert 'pixel' not in skipped and 'hold_start_s' not in skipped
    assert 'skipped' not in held and held['hold_end_s'] - held['hold_start_s'] == pytest.approx(2.0)
    with BagReader(bag) as reader:
        steps = [message for _, _, message in reader.messages(CALIBRATION_PROGRESS.name)]
        fine_drive_deg = np.degrees([[m.joint_positions_of(message)[joint] for joint in FD_JOINTS]
                                     for _, _, message in reader.messages(JOINT_STATES.name)])
    warnings = [step for step in steps if step.message == 'element_skipped']
    assert len(warnings) == 1 and warnings[0].level == ord(DiagnosticStatus.WARN)  # the bag's level: an int
    assert m.status_values_of(warnings[0])['index'] == '1'
    # Refused, not flown: the fine drive never left its travel (the XEL came within 0.2 deg of it).
    assert 2.8 < np.max(np.abs(fine_drive_deg)) <= 3.0


def test_each_star_hop_element_records_its_flight_window(flown):
    summary, result, _ = flown
    elements = result['elements']
    # The first element's flight starts after the last observation's hold (and its park), slew included.
    assert elements[0]['start_s'] >= result['observations'][-1]['hold_end_s']
    for before, after in zip(elements, elements[1:]):
        assert after['start_s'] == before['end_s']  # back to back: each window ends with its park
    for element in elements:
        assert element['start_s'] < element['end_s'] <= summary['sim_seconds']
    held = elements[1]
    assert held['start_s'] < held['hold_start_s'] < held['hold_end_s'] <= held['end_s']


@pytest.mark.parametrize('latest_answer, skipped', [
    ('refused: fine drive XEL would reach +3.100 deg, beyond the +-3 deg travel', True),
    ('done', False),  # the element timed out waiting for frames: the graph is at fault, the run stops
    (None, False),  # no command answered yet
], ids=['refused', 'timed out after a done command', 'nothing answered'])
def test_only_a_refused_command_skips_an_element(latest_answer, skipped):
    core = StarHopCore(PLAN, None)
    core.command_status = {1: 'refused: an earlier element', 2: latest_answer} if latest_answer else {}

    def fly_hold(element):
        raise CalibrationAbort('timed out after 180 s waiting for 1 FFI frames with HIP 105199')
        yield

    core._fly_hold = fly_hold
    flight = core._fly_within_reach(1, PLAN.elements[0])
    if not skipped:
        with pytest.raises(CalibrationAbort, match='timed out after 180 s'):
            next(flight)
        return
    with pytest.raises(StopIteration) as stopped:
        next(flight)
    assert stopped.value.value == {'kind': 'hold', 'star': 'Alpha Cep',
                                   'skipped': "out of the telescope's reach: " + latest_answer[len('refused: '):]}
    (warning,) = [message for _, message in core.outbox]
    assert warning.message == 'element_skipped' and warning.level == DiagnosticStatus.WARN


def test_the_thermal_truths_description_states_its_limits():
    truth = yaml.safe_load(THERMAL.read_text())
    control = truth['scenario']['thermal_control']
    description = ' '.join(truth['description'].split())
    assert f'{control["min_c"]:g}-{control["max_c"]:g} C' in description
    assert f'at most {control["max_rate_c_per_h"]:g} C/h' in description
    assert f'({control["time_constant_s"]:g} s) time constant' in description
