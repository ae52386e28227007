"""The star hop with one OS process per node (`sofia run star-hop --processes`), and its node parameters.

Reduced size: Table D.3 observations 15-17 (HIP 47193, Polaris, Xi Cep) with 10 s holds, each
star flown as soon as the previous one is done (about 140 s of sim time). The processes run must
record what the direct run of the same truth, seed and plan records: the same topics with the same
counts, the same documents, the same observations.
"""

import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from graph_startup import STARTUP_RERUNS
from sofia_ros.bag import BagReader
from sofia_ros.campaigns.graph_params import GRAPH_PARAMETERS, graph_config_from_parameters, plan_from_parameters
from sofia_ros.campaigns.run_parameters import graph_parameters, plan_parameters
from sofia_ros.campaigns.star_hop import run_star_hop
from sofia_ros.cli import main
from sofia_ros.config import load_effect_config
from sofia_ros.errors import ConfigError
from sofia_ros.nodes.launch import write_params_file
from sofia_ros.sim.calibration import AlignmentPlan
from sofia_ros.sim.star_hop import StarHopPlan, table_d3_offsets_s
from sofia_ros.topics import DEFAULT_TICK_NS

ROOT = Path(__file__).resolve().parents[1]
TRUTH_FILE = ROOT / 'config' / 'truth' / 'nominal.yaml'
# The same plan as `sofia run star-hop --observations 15-17 --hold-s 10 --no-follow-times`.
PLAN = StarHopPlan(observations=table_d3_offsets_s()[14:17], hold_s=10.0, follow_times=False)
CLI_PLAN = ['--observations', '15-17', '--hold-s', '10', '--no-follow-times']
DOCUMENTS = ('/config/truth', '/config/model', '/config/scenario', '/config/plan')
SEED = 5


@pytest.fixture(scope='module')
def direct_bag(tmp_path_factory):
    bag = tmp_path_factory.mktemp('direct') / 'bag'
    summary = run_star_hop(load_effect_config(TRUTH_FILE), seed=SEED, bag_path=bag, plan=PLAN, mode='direct')
    assert summary['finished'] and summary['observations'] == 3
    return bag


def _topic_counts(path):
    """Messages per topic of a closed bag, without documents and /parameter_events (not lock-stepped)."""
    with BagReader(path) as bag:
        return {topic.name: topic.count for topic in bag.topics if not topic.name.startswith(('/config', '/result'))
                and topic.name != '/parameter_events'}


def _documents(path):
    with BagReader(path) as bag:
        return {topic: bag.document(topic) for topic in DOCUMENTS}


def _observations(path):
    return yaml.safe_load((path / 'star_hop.yaml').read_text())['observations']


def _params(**plan_values):
    """Parameter values of a star-hop run with some plan.* values replaced."""
    values = graph_parameters(TRUTH_FILE, SEED, PLAN, tick_ns=DEFAULT_TICK_NS, max_sim_s=600.0)
    values.update(plan_values)
    return values


@pytest.mark.timeout(600)
@STARTUP_RERUNS
def test_processes_run_records_what_the_direct_run_records(direct_bag, tmp_path, private_tmp, capsys):
    bag = tmp_path / 'processes'
    code = main(['run', 'star-hop', '--truth', str(TRUTH_FILE), '--seed', str(SEED), '--bag', str(bag),
                 '--processes', *CLI_PLAN])
    out, err = capsys.readouterr()
    assert code == 0 and '3 observations' in out, err
    # The node logs of a finished run are cleaned up.
    assert not list(private_tmp.glob('sofia_graph_*'))
    summary = yaml.safe_load((bag / 'summary.json').read_text())
    assert summary['finished'] and summary['observations'] == 3
    # The recorder closed the bag (BagReader also refuses one without metadata.yaml).
    assert (bag / 'metadata.yaml').exists()
    assert _topic_counts(bag) == _topic_counts(direct_bag)
    assert _documents(bag) == _documents(direct_bag)
    assert yaml.safe_load(_documents(bag)['/config/plan'])['observations'] == [list(row) for row in PLAN.observations]
    assert _observations(bag) == _observations(direct_bag)


@pytest.mark.parametrize('plan', [PLAN, StarHopPlan(), AlignmentPlan(repetitions=4, flexure_elevations_deg=(30.0,))])
def test_plan_parameters_give_back_the_plan(plan):
    campaign = 'alignment' if isinstance(plan, AlignmentPlan) else 'star-hop'
    assert plan_from_parameters(campaign, plan_parameters(plan)) == plan


def test_star_hop_parameters_build_the_star_hop_graph():
    config = graph_config_from_parameters(_params())
    assert config.plan == PLAN and config.seed == SEED
    assert _params()['plan.observations.star'] == ['HIP 47193', 'Polaris', 'Xi Cep']


def test_a_bad_campaign_parameter_names_the_campaigns():
    with pytest.raises(ConfigError, match=r"campaign is 'star_hop'; use one of alignment, star-hop"):
        graph_config_from_parameters(_params(campaign='star_hop'))


@pytest.mark.parametrize('plan_values, message', [
    ({'plan.observations.star': ['Polaris', 'Xi Cep']},
     r'plan.observations.star has 2, plan.observations.offset_s has 3 entries; give plan.observations.star and '
     r'plan.observations.offset_s with one entry per row'),
    ({'plan.observations.offset_s': ['0', '10', '20']}, r'plan.observations.offset_s must be an array of numbers'),
    ({'plan.observations.star': 'Polaris'}, r'plan.observations.star must be an array of strings'),
    ({'plan.observations.star': ['Polaris', 'Vega Prime', 'Xi Cep']},
     r"plan.\* parameters of the star-hop campaign: unknown star name 'Vega Prime'"),
    ({'plan.observations': ['Polaris', 'Xi Cep']}, r'the star-hop plan has no parameter plan.observations;'),
    ({'plan.repetitions': 4}, r'the star-hop plan has no parameter plan.repetitions; its plan parameters are '
                              r'plan.observations.star, plan.observations.offset_s, plan.hold_s'),
    ({'plan.follow_times': 'no'}, r'plan.follow_times must be true or false'),
])
def test_a_malformed_plan_parameter_is_one_clear_config_error(plan_values, message):
    with pytest.raises(ConfigError, match=message):
        graph_config_from_parameters(_params(**plan_values))


@pytest.mark.timeout(60)
def test_a_node_with_malformed_observations_exits_2_with_one_line(tmp_path):
    # Through rclpy's own parsing of a params file: string and double arrays of unequal length.
    params = tmp_path / 'params.yaml'
    write_params_file(params, _params(**{'plan.observations.offset_s': [0.0, 100.0]}))
    result = subprocess.run([sys.executable, '-m', 'sofia_ros.nodes.executables', 'clock', '--ros-args',
                             '--params-file', str(params)], capture_output=True, text=True, timeout=50)
    assert result.returncode == 2
    assert result.stderr.strip() == ('clock: error: plan.observations.star has 3, plan.observations.offset_s has 2 '
                                     'entries; give plan.observations.star and plan.observations.offset_s with one '
                                     'entry per row of plan.observations')


def test_shipped_star_hop_params_file_builds_the_table_d3_graph():
    document = yaml.safe_load((ROOT / 'config' / 'star_hop.params.yaml').read_text())
    config = graph_config_from_parameters(document['/**']['ros__parameters'])
    assert config.plan == StarHopPlan() and config.tick_ns == DEFAULT_TICK_NS


@pytest.mark.timeout(60)
def test_a_node_process_reads_its_parameters_as_rcl_resolves_them_for_its_remapped_name(tmp_path):
    # The params file's wildcard section, the section of the node's remapped name, -p on top; read without an rclpy
    # Node of its own (whose writers, destroyed at start-up, could deadlock Fast DDS: nodes.executables).
    import rclpy

    from sofia_ros.nodes.executables import _read_parameters

    params = tmp_path / 'params.yaml'
    write_params_file(params, {'seed': 5, 'max_sim_s': 99.0, 'plan.hold_s': 30.0},
                      per_node={'fpi': {'camera': 'fpi'}, 'ffi': {'camera': 'ffi'}})
    rclpy.init(args=['imager', '--ros-args', '--params-file', str(params), '-p', 'max_sim_s:=12.5',
                     '-r', '__node:=fpi'])
    try:
        values = _read_parameters('imager')
        observer = rclpy.create_node('observer', use_global_arguments=False)
        names = observer.get_node_names()
    finally:
        rclpy.try_shutdown()
    assert (values['seed'], values['max_sim_s'], values['camera'], values['plan.hold_s']) == (5, 12.5, 'fpi', 30.0)
    assert values['campaign'] == GRAPH_PARAMETERS['campaign'][0]  # not given: its default
    assert names == ['observer']  # the reader left nothing in the graph
