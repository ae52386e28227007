"""The temperature plan element (docs/plans.md: Temperature): a truth's thermal control, the lag that follows its
setpoint, the element's checks before the run, and a flown plateau in the recorded temperature."""

import dataclasses
import re
from pathlib import Path

import numpy as np
import pytest
import yaml
from scipy.integrate import solve_ivp

from sofia_ros import messages as m
from sofia_ros.bag import BagReader
from sofia_ros.campaigns.alignment import default_scenario, graph_config
from sofia_ros.campaigns.graph_params import plan_from_parameters
from sofia_ros.campaigns.plan_files import read_plan_file, write_plan_file
from sofia_ros.campaigns.run_parameters import plan_parameters
from sofia_ros.campaigns.star_hop import star_hop_config
from sofia_ros.cli import main
from sofia_ros.compare.observations import read_observations
from sofia_ros.config import load_effect_config, parse_effect_config
from sofia_ros.errors import ConfigError
from sofia_ros.scenario import (
    ThermalControl,
    ThermalHistory,
    lagged_temperature_c,
    scenario_document,
    scenario_from_document,
)
from sofia_ros.sim.calibration import AlignmentPlan
from sofia_ros.sim.camera import CameraCore
from sofia_ros.sim.plant import PlantCore
from sofia_ros.sim.star_hop import StarHopPlan, table_d3_offsets_s
from sofia_ros.topics import GYRO_TEMPERATURE, THERMAL_COMMAND, TRUTH_TEMPERATURE

ROOT = Path(__file__).resolve().parents[1]
NOMINAL = ROOT / 'config' / 'truth' / 'nominal.yaml'
THERMAL = ROOT / 'config' / 'truth' / 'nominal-thermal.yaml'
CONTROL = ThermalControl(min_c=10.0, max_c=35.0, max_rate_c_per_h=60.0, time_constant_s=120.0)
MINIMAL = (ROOT / 'config' / 'plans' / 'alignment-minimal.yaml').read_text()


# --- the physics: a first-order lag behind a slewed setpoint ---------------------------------------------
@pytest.mark.parametrize('start_c, target_c, rate_c_per_h', [(22.0, 26.0, 60.0), (22.0, 19.5, 12.0), (22.0, 22.0, 5.0)])
def test_the_lag_is_the_first_order_equation_integrated(start_c, target_c, rate_c_per_h):
    tau_s, start_s = 120.0, 50.0
    slew_s = abs(target_c - start_c) / rate_c_per_h * 3600.0

    def setpoint(t):
        return start_c + np.sign(target_c - start_c) * min(rate_c_per_h / 3600.0 * (t - start_s),
                                                            abs(target_c - start_c))
    times = np.linspace(start_s, start_s + slew_s + 900.0, 60)
    solved = solve_ivp(lambda t, y: (setpoint(t) - y) / tau_s, (times[0], times[-1]), [start_c], t_eval=times,
                       rtol=1e-10, atol=1e-12, max_step=5.0)
    lagged = [lagged_temperature_c(t, start_s, start_c, target_c, rate_c_per_h, tau_s) for t in times]
    np.testing.assert_allclose(lagged, solved.y[0], atol=1e-7)
    assert lagged[0] == start_c


def test_without_a_command_the_history_is_the_scenarios_drift_to_the_bit():
    scenario = dataclasses.replace(default_scenario(), thermal_control=CONTROL)
    history = ThermalHistory(scenario)
    times = np.arange(0.0, 3600.0, 0.2)
    assert [history.temperature_c_at(t) for t in times] == [scenario.temperature_c_at(t) for t in times]
    history.command(100.0, 26.0, 30.0)
    # Before its start a command changes nothing; from it on the temperature is continuous.
    assert history.temperature_c_at(99.8) == scenario.temperature_c_at(99.8)
    assert history.temperature_c_at(100.0) == scenario.temperature_c_at(100.0)
    assert history.temperature_c_at(100.0 + 3600.0) == pytest.approx(26.0, abs=1e-6)


def test_a_controller_saturates_and_a_truth_without_one_follows_nothing():
    scenario = dataclasses.replace(default_scenario(), thermal_control=CONTROL)
    history = ThermalHistory(scenario)
    history.command(0.0, 80.0, 1000.0)  # beyond the range and the rate: held at 35 C and 60 C/h
    assert history.commands[0][2:] == (35.0, 60.0)
    history.command(10.0, float('nan'), 10.0)
    assert len(history.commands) == 1
    uncontrolled = ThermalHistory(default_scenario())
    uncontrolled.command(0.0, 30.0, 10.0)
    assert uncontrolled.commands == []
    assert uncontrolled.temperature_c_at(600.0) == default_scenario().temperature_c_at(600.0)


def test_the_plant_and_the_cameras_follow_the_same_commands():
    truth = load_effect_config(THERMAL)
    scenario = graph_config(truth, 0).scenario
    plant, camera = PlantCore(scenario, truth.effects), CameraCore('fpi', scenario, truth.effects)
    command = m.vector3_stamped(m.seconds_to_ns(10.0), 'tarf', (27.0, 40.0 / 3600.0, 0.0))
    for core in (plant, camera):
        core.receive(THERMAL_COMMAND.name, command)
    times = np.arange(0.0, 900.0, 0.7)
    assert [plant.thermal.temperature_c_at(t) for t in times] == [camera.thermal.temperature_c_at(t) for t in times]
    published = dict(plant.tick(m.seconds_to_ns(400.0)))[TRUTH_TEMPERATURE.name].temperature
    assert published == plant.thermal.temperature_c_at(400.0) > scenario.temperature_c_at(400.0) + 2.0


# --- the truth's thermal_control and the element: checked before the run --------------------------------
def test_a_thermal_control_is_read_from_the_truth_and_recorded_in_the_scenario_document():
    scenario = graph_config(load_effect_config(THERMAL), 0).scenario
    assert scenario.thermal_control == CONTROL
    assert scenario_from_document(scenario_document(scenario)) == scenario
    nominal = graph_config(load_effect_config(NOMINAL), 0).scenario
    assert nominal.thermal_control is None and 'thermal_control' not in scenario_document(nominal)


@pytest.mark.parametrize('control, message', [
    ('{min_c: 10, max_c: 35, max_rate_c_per_h: 60}', r'thermal_control must map exactly min_c, max_c, '
                                                     r'max_rate_c_per_h, time_constant_s'),
    ('{min_c: 30, max_c: 20, max_rate_c_per_h: 60, time_constant_s: 60}', r'min_c 30 must be below max_c 20'),
    ('{min_c: 10, max_c: 35, max_rate_c_per_h: 0, time_constant_s: 60}', r'max_rate_c_per_h must be > 0, got 0'),
    ('{min_c: 10, max_c: 35, max_rate_c_per_h: 60, time_constant_s: -5}', r'time_constant_s = -5 is outside'),
    ('{min_c: 10, max_c: 95, max_rate_c_per_h: 60, time_constant_s: 60}', r'max_c = 95 is outside \[-80, 60\]'),
    ('{min_c: cold, max_c: 35, max_rate_c_per_h: 60, time_constant_s: 60}', r"min_c must be a number in"),
    ('[10, 35]', r'thermal_control must map exactly'),
])
def test_a_bad_thermal_control_is_one_config_error(control, message):
    with pytest.raises(ConfigError, match=message):
        parse_effect_config(f'effects: {{}}\nscenario:\n  thermal_control: {control}\n', 'truth.yaml')


ALIGNMENT_PLATEAU = 'campaign: alignment\nelements:\n  - temperature: {target_c: 26, duration_s: 60}\n'
BAD_PLANS = {
    'no target': ('alignment', NOMINAL, 'campaign: alignment\nelements:\n  - temperature: {duration_s: 60}\n',
                  r'element 1 \(temperature\) needs target_c, duration_s'),
    'a target that is no number': ('alignment', THERMAL,
                                   'campaign: alignment\nelements:\n  - temperature: {target_c: warm, duration_s: 6}\n',
                                   r'element 1 \(temperature\): target_c'),
    'a rate of 0': ('alignment', THERMAL, 'campaign: alignment\nelements:\n'
                                          '  - temperature: {target_c: 26, rate_c_per_h: 0, duration_s: 60}\n',
                    r'rate_c_per_h must be > 0 C/h'),
    'a hold of 0 s': ('star-hop', THERMAL, 'campaign: star-hop\nelements:\n'
                                           '  - temperature: {star: Polaris, target_c: 26, duration_s: 0}\n',
                      r'duration_s must be > 0 and <= 7200 s, got 0'),
    'an unknown star': ('star-hop', THERMAL, 'campaign: star-hop\nelements:\n'
                                             '  - temperature: {star: Vulcan, target_c: 26, duration_s: 5}\n',
                        r"unknown star name 'Vulcan'"),
    'an unknown field': ('alignment', THERMAL, 'campaign: alignment\nelements:\n'
                                               '  - temperature: {plateau_c: 26, duration_s: 60}\n',
                         r'unknown field plateau_c; temperature takes target_c, duration_s, rate_c_per_h'),
    'another name for it': ('alignment', THERMAL, 'campaign: alignment\nelements:\n'
                                                  '  - temperature_plateau: {target_c: 26, duration_s: 60}\n',
                            r'element temperature_plateau: .* - temperature: \{target_c: T, duration_s: S\}'),
    'a top-level temperature': ('alignment', THERMAL, 'campaign: alignment\ntemperature: 26\n',
                                r'temperature: .*thermal_control, the elements of the form - temperature:'),
    'a truth without thermal control': ('alignment', NOMINAL, ALIGNMENT_PLATEAU,
                                        r'element 1 \(temperature\): the truth .*nominal.yaml has no '
                                        r'scenario.thermal_control, so nothing can command its temperature; fly it '
                                        r'on a truth that has one, e.g. config/truth/nominal-thermal.yaml'),
    'a star hop on a truth without thermal control': (
        'star-hop', NOMINAL, 'campaign: star-hop\nelements:\n  - temperature: {star: Polaris, target_c: 26, '
                             'duration_s: 5}\n', r'element 1 \(temperature\): the truth .* has no'),
    'a target beyond the range': ('alignment', THERMAL, ALIGNMENT_PLATEAU.replace('26', '40'),
                                  r"element 1 \(temperature\): target_c 40 C is outside the 10 to 35 C the truth's "
                                  r'thermal control reaches \(scenario.thermal_control of .*nominal-thermal.yaml\)'),
    'a rate beyond the largest': ('alignment', THERMAL, 'campaign: alignment\nelements:\n  - hold: {duration_s: 5}\n'
                                                        '  - temperature: {target_c: 20, rate_c_per_h: 90, '
                                                        'duration_s: 60}\n',
                                  r'element 2 \(temperature\): rate_c_per_h 90 C/h is outside \(0, 60\] C/h'),
}


@pytest.mark.parametrize('campaign, truth, text, message', BAD_PLANS.values(), ids=BAD_PLANS)
def test_sofia_run_refuses_a_temperature_element_it_cannot_fly_in_one_line(campaign, truth, text, message, tmp_path,
                                                                           capsys):
    path = tmp_path / 'plan.yaml'
    path.write_text(text)
    bag = tmp_path / 'bag'
    code = main(['run', campaign, '--truth', str(truth), '--plan', str(path), '--bag', str(bag), '--direct'])
    captured = capsys.readouterr()
    lines = captured.err.strip().splitlines()
    assert code == 2 and len(lines) == 1 and lines[0].startswith('sofia: error: ')
    assert re.search(message, lines[0]) and 'Traceback' not in captured.err
    assert not bag.exists() and captured.out == '' and list(tmp_path.iterdir()) == [path]


def test_the_config_builders_refuse_what_the_truth_cannot_fly():
    plan = StarHopPlan(elements_yaml='[{temperature: {star: Polaris, target_c: 8, duration_s: 5}}]')
    with pytest.raises(ConfigError, match=r'target_c 8 C is outside the 10 to 35 C'):
        star_hop_config(load_effect_config(THERMAL), 0, plan)
    assert star_hop_config(load_effect_config(THERMAL), 0, dataclasses.replace(plan, elements_yaml=plan.elements_yaml
                                                                               .replace('8', '12'))).plan.elements


@pytest.mark.parametrize('plan', [
    AlignmentPlan(elements_yaml='[{temperature: {target_c: 26, duration_s: 60}}, '
                                '{temperature: {target_c: 21.5, rate_c_per_h: 12, duration_s: 900, los_deg: 1}}]'),
    StarHopPlan(observations=table_d3_offsets_s()[:2],
                elements_yaml='[{temperature: {star: Polaris, target_c: 26, rate_c_per_h: 6, duration_s: 30}}]'),
], ids=['alignment', 'star-hop'])
def test_a_temperature_element_reads_back_from_a_file_and_from_node_parameters(plan, tmp_path):
    assert read_plan_file(write_plan_file(plan, tmp_path / 'plan.yaml'), plan.campaign) == plan
    assert plan_from_parameters(plan.campaign, plan_parameters(plan)) == plan


def test_the_example_plan_flies_on_the_thermal_truth():
    plan = read_plan_file(ROOT / 'config' / 'plans' / 'examples' / 'alignment-thermal-plateau.yaml', 'alignment')
    assert [element.kind for element in graph_config(load_effect_config(THERMAL), 0, plan).plan.elements] == [
        'temperature']


# --- flown -----------------------------------------------------------------------------------------------
FAST_CONTROL = {'min_c': 10.0, 'max_c': 35.0, 'max_rate_c_per_h': 100.0, 'time_constant_s': 10.0}


@pytest.fixture(scope='module')
def plateau_flown(tmp_path_factory):
    """The minimal alignment, then a plateau at 24 C held 100 s, on the nominal truth with a fast thermal control
    (the setpoint's slew of about 1.3 C takes 46 s, three time constants 30 s)."""
    folder = tmp_path_factory.mktemp('plateau')
    truth = yaml.safe_load(NOMINAL.read_text())
    truth['scenario'] = {'thermal_control': FAST_CONTROL}
    (folder / 'truth.yaml').write_text(yaml.safe_dump(truth))
    (folder / 'plan.yaml').write_text(MINIMAL + 'elements:\n  - temperature: {target_c: 24, duration_s: 100}\n')
    bag = folder / 'bag'
    assert main(['run', 'alignment', '--truth', str(folder / 'truth.yaml'), '--seed', '2', '--plan',
                 str(folder / 'plan.yaml'), '--bag', str(bag), '--direct']) == 0
    return bag


def test_a_flown_plateau_moves_the_recorded_temperature_to_it_within_the_time_constant(plateau_flown):
    (element,) = yaml.safe_load((plateau_flown / 'calibration.yaml').read_text())['elements']
    assert element['kind'] == 'temperature' and element['target_c'] == 24.0 and element['rate_c_per_h'] == 100.0
    assert element['command_s'] == element['hold_start_s'] and element['hold_end_s'] - element['hold_start_s'] >= 100
    scenario = graph_config(load_effect_config(plateau_flown / 'truth.yaml'), 2).scenario
    expected = ThermalHistory(scenario)
    expected.command(element['command_s'], 24.0, 100.0)
    gyro = read_observations(plateau_flown).gyro  # the temperature compare reads: /gyro_box/temperature
    assert np.array_equal(gyro.tick_temperature_c, [expected.temperature_c_at(t) for t in gyro.tick_end_s])
    before = gyro.tick_end_s <= element['command_s']
    drift_c = [scenario.temperature_c_at(t) for t in gyro.tick_end_s[before]]
    assert np.array_equal(gyro.tick_temperature_c[before], drift_c)
    step_c = 24.0 - scenario.temperature_c_at(element['command_s'])
    slew_s = step_c / 100.0 * 3600.0
    # Past the slew, within one time constant the lag covers 63 % of what remains, within three 95 %.
    tau_s = FAST_CONTROL['time_constant_s']
    for lag_taus, share in ((1.0, 0.63), (3.0, 0.95)):
        after = gyro.tick_end_s >= element['command_s'] + slew_s + lag_taus * tau_s
        rise_c = gyro.tick_temperature_c[after] - scenario.temperature_c_at(element['command_s'])
        assert np.count_nonzero(after) >= 50 and np.all(rise_c >= share * step_c)
    assert gyro.tick_temperature_c[-1] == pytest.approx(24.0, abs=0.01 * step_c)  # five time constants after the slew
    with BagReader(plateau_flown) as bag:
        assert bag.topic(THERMAL_COMMAND.name).count == 1


def test_the_default_truths_temperature_is_the_scenarios_drift_to_the_bit(campaign_bags):
    bag = campaign_bags.reduced_alignment()
    scenario = graph_config(load_effect_config(NOMINAL), 3).scenario
    with BagReader(bag, campaign_time=True) as reader:  # stamps in s since the start, as the plant's
        records = reader.messages_by_topic(GYRO_TEMPERATURE.name, TRUTH_TEMPERATURE.name)
        assert reader.topic(THERMAL_COMMAND.name).count == 0
    for topic in (GYRO_TEMPERATURE.name, TRUTH_TEMPERATURE.name):
        messages = records[topic][1]
        stamps_s = [m.stamp_ns_of(message.header.stamp) / m.NS_PER_S for message in messages]
        assert len(messages) > 1000
        assert [message.temperature for message in messages] == [scenario.temperature_c_at(t) for t in stamps_s]


def test_a_star_hop_ramp_is_flown_on_the_thermal_truth(tmp_path):
    plan = tmp_path / 'plan.yaml'
    plan.write_text('campaign: star-hop\nobservations: [[Polaris, 5494.0], [Xi Cep, 5687.0]]\nhold_s: 5\n'
                    'follow_times: false\nelements:\n'
                    '  - temperature: {star: Xi Cep, target_c: 24, rate_c_per_h: 50, duration_s: 20}\n')
    bag = tmp_path / 'bag'
    assert main(['run', 'star-hop', '--truth', str(THERMAL), '--seed', '2', '--plan', str(plan), '--bag', str(bag),
                 '--direct']) == 0
    (element,) = yaml.safe_load((bag / 'star_hop.yaml').read_text())['elements']
    assert (element['kind'], element['star'], element['rate_c_per_h']) == ('temperature', 'Xi Cep', 50.0)
    scenario = star_hop_config(load_effect_config(THERMAL), 2, read_plan_file(plan)).scenario
    expected = ThermalHistory(scenario)
    expected.command(element['command_s'], 24.0, 50.0)
    gyro = read_observations(bag).gyro
    assert np.array_equal(gyro.tick_temperature_c, [expected.temperature_c_at(t) for t in gyro.tick_end_s])
    # At the hold's end, 20 s into a ramp of 50 C/h behind the truth's 120 s lag: 0.022 C above the start (the
    # night's drift alone would be 0.006 C below it).
    end = np.argmin(np.abs(gyro.tick_end_s - element['hold_end_s']))
    rise_c = gyro.tick_temperature_c[end] - scenario.temperature_c_at(element['command_s'])
    assert rise_c == pytest.approx(50.0 / 3600.0 * (20.0 + 120.0 * np.expm1(-20.0 / 120.0)), rel=0.02)


def test_a_hipo_clock_behind_sends_no_frame_stamped_before_the_start(tmp_path):
    # timestamp_offset -0.4 s (its range is +-60 s) stamped HIPO's first frames before the campaign's start, where the
    # bag's time begins: `sofia run` stopped at once ("stamp_ns must be >= 0"), exit 2, a broken bag left behind.
    from sofia_ros.bag import BagWriter
    from sofia_ros.sim.graph import build_cores
    from sofia_ros.sim.runner import LockstepRunner

    truth = parse_effect_config(NOMINAL.read_text() + '  timestamp_offset: {offset_s: -0.4}\n')
    config = graph_config(truth, 8)
    with BagWriter(tmp_path / 'bag') as bag:
        runner = LockstepRunner(build_cores(config), tick_ns=config.tick_ns, bag=bag)
        runner.run(until_ns=m.seconds_to_ns(3.0))
    with BagReader(tmp_path / 'bag') as bag:
        stamps_ns, _ = bag.messages_by_topic('/hipo/centroids', raw=('/hipo/centroids',))['/hipo/centroids']
    assert len(stamps_ns) > 0 and stamps_ns[0] >= 0
