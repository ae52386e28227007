"""The README stays true: its topic table is the graph's, its commands exist."""

from pathlib import Path

from sofia_ros.campaigns.alignment import graph_config
from sofia_ros.cli import build_parser
from sofia_ros.config import load_effect_config
from sofia_ros.sim.graph import topic_table_markdown
from sofia_ros.topics import DEFAULT_TICK_NS

REPO = Path(__file__).resolve().parents[1]
README = (REPO / 'README.md').read_text()


def test_topic_table_is_the_graphs():
    table = topic_table_markdown(graph_config(load_effect_config('config/truth/nominal.yaml'), 0))
    assert table in README
    assert table in (REPO / 'docs' / 'topics.md').read_text()


def test_every_document_the_readme_links_exists():
    import re

    linked = set(re.findall(r'\]\((docs/[^)#]+)\)', README))
    assert {'docs/cli.md', 'docs/compare.md', 'docs/noise.md', 'docs/effects.md', 'docs/topics.md', 'docs/bag.md',
            'docs/conventions.md'} <= linked
    assert all((REPO / path).is_file() for path in linked)


def test_readme_opens_with_the_two_commands():
    first_block = README.split('```')[1]
    assert 'scripts/run-main' in first_block and 'scripts/run-tests' in first_block
    assert 'scripts/run-tests' in (Path(__file__).resolve().parents[1] / '.ci' / 'run').read_text()


def test_every_documented_verb_exists():
    verbs = build_parser()._subparsers._group_actions[0].choices
    for verb in ('run', 'replay', 'effects', 'demo', 'compare', 'noise', 'model', 'import', 'perturb'):
        assert verb in verbs and f'sofia {verb}' in README


def test_shipped_params_file_builds_the_graph():
    import yaml

    from sofia_ros.campaigns.graph_params import graph_config_from_parameters

    document = yaml.safe_load((Path(__file__).resolve().parents[1] / 'config/alignment.params.yaml').read_text())
    config = graph_config_from_parameters(document['/**']['ros__parameters'])
    assert config.plan.repetitions == 6 and config.tick_ns == DEFAULT_TICK_NS
