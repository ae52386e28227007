"""Every node, topic and campaign is in each registry it must be in (CONTRIBUTING.md lists them)."""

from pathlib import Path

import pytest

from sofia_ros import graph_nodes, topics
from sofia_ros.campaigns import graph_params
from sofia_ros.campaigns.registry import CAMPAIGNS
from sofia_ros.cli import main
from sofia_ros.config import load_effect_config
from sofia_ros.nodes import executables
from sofia_ros.sim.graph import build_core, build_cores, graph_topics

ROOT = Path(__file__).resolve().parents[1]
NOMINAL = load_effect_config(ROOT / 'config' / 'truth' / 'nominal.yaml')
GRAPH_CAMPAIGNS = [spec for spec in CAMPAIGNS.values() if spec.build_config is not None]


@pytest.fixture(scope='module', params=[spec.name for spec in GRAPH_CAMPAIGNS])
def cores(request):
    """Every core of one graph campaign, built from its reduced plan."""
    spec = CAMPAIGNS[request.param]
    return build_cores(spec.build_config(NOMINAL, 3, spec.plan('reduced')))


def test_every_node_has_a_core_and_an_executable():
    runs = {node for nodes in graph_nodes.EXECUTABLES.values() for node in nodes}
    assert set(graph_nodes.NODE_NAMES) | {'recorder'} == runs
    for executable in graph_nodes.EXECUTABLES:
        assert callable(getattr(executables, executable)) and executable in executables.__all__
    for setup_line in ('graph_nodes.py', 'EXECUTABLES'):
        assert setup_line in (ROOT / 'setup.py').read_text()  # the console scripts are read from the registry
    assert set(graph_nodes.SEEDED_NODES) <= set(graph_nodes.NODE_NAMES)
    assert graph_nodes.CAMERAS == ('hipo', *graph_nodes.IMAGERS)


def test_each_core_is_the_node_it_is_built_for(cores):
    assert [core.name for core in cores] == list(graph_nodes.NODE_NAMES)
    assert [core.name for core in cores if core.ends_run] == ['calibration']
    named = {core.name for core in cores}
    for core in cores:
        assert {node for node, _ in core.upstream} <= named
        assert set(core.parameter_targets) <= named


def test_every_topic_of_the_graph_is_in_topics_py(cores):
    registered = {spec.name: spec for spec in topics.GRAPH_TOPICS}
    for core in cores:
        for spec in core.outputs():
            assert registered.get(spec.name) == spec, f'{core.name} publishes {spec.name}, not in sofia_ros.topics'
            assert spec.publisher == core.name
        for spec in core.inputs():
            assert registered.get(spec.name) == spec, f'{core.name} reads {spec.name}, not in sofia_ros.topics'
    published = {name for name, (_, publisher, _) in graph_topics(cores).items() if publisher}
    assert published == set(registered)


def test_every_graph_topic_is_in_the_topic_table():
    table = (ROOT / 'docs' / 'topics.md').read_text()
    for spec in topics.GRAPH_TOPICS:
        assert f'| `{spec.name}` | `{spec.msgtype}` | {spec.publisher} |' in table


def test_every_campaign_is_runnable_and_named_everywhere(capsys):
    assert main(['run', '--help']) == 0
    help_text = capsys.readouterr().out
    cli_doc = (ROOT / 'docs' / 'cli.md').read_text()
    for spec in CAMPAIGNS.values():
        assert spec.name in help_text and f'sofia run {spec.name}' in cli_doc
        assert callable(spec.run) and set(spec.analyses) <= {'compare', 'noise'}
    for spec in GRAPH_CAMPAIGNS:
        plan = spec.plan()
        assert plan.campaign == spec.name and CAMPAIGNS[plan.campaign] is spec
        assert spec.name in graph_params.CAMPAIGNS
    assert set(graph_params.CAMPAIGNS) == {spec.name for spec in GRAPH_CAMPAIGNS}


def test_an_unknown_node_is_one_line():
    spec = GRAPH_CAMPAIGNS[0]
    config = spec.build_config(NOMINAL, 3, spec.plan('reduced'))
    from sofia_ros.errors import ConfigError

    with pytest.raises(ConfigError, match="unknown node 'imager'; nodes are clock, plant"):
        build_core('imager', config)
