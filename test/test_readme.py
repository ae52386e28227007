"""The README stays a true front door: short, its commands exist, every document it points to is there."""

import re
import shlex
from pathlib import Path

import pytest

from sofia_ros.campaigns.alignment import graph_config
from sofia_ros.cli import build_parser
from sofia_ros.config import load_effect_config
from sofia_ros.sim.graph import topic_table_markdown
from sofia_ros.topics import DEFAULT_TICK_NS

REPO = Path(__file__).resolve().parents[1]
README = (REPO / 'README.md').read_text()
# The README and the documents that took over its content (issue 26); their links must all resolve.
LINKING_DOCUMENTS = [REPO / 'README.md', REPO / 'docs' / 'install.md', REPO / 'docs' / 'thesis-2004.md',
                     REPO / 'bench' / 'RESULTS.md', *sorted((REPO / 'docs' / 'tutorials').glob('*.md'))]
MAX_README_LINES = 260
MAX_README_LINE_CHARS = 200


def test_topic_table_in_the_docs_is_the_graphs():
    table = topic_table_markdown(graph_config(load_effect_config('config/truth/nominal.yaml'), 0))
    assert table in (REPO / 'docs' / 'topics.md').read_text()


def test_readme_is_a_front_door_not_a_notebook():
    lines = README.split('\n')
    assert len(README.splitlines()) <= MAX_README_LINES
    too_long = [number for number, line in enumerate(lines, 1) if len(line) > MAX_README_LINE_CHARS]
    assert too_long == [], f'README lines over {MAX_README_LINE_CHARS} characters: {too_long}'


def test_the_readme_maps_every_document():
    linked = set(re.findall(r'\]\((docs/[^)#]+)', README))
    documents = {path.relative_to(REPO).as_posix()
                 for path in [*(REPO / 'docs').glob('*.md'), *(REPO / 'docs' / 'tutorials').glob('*.md')]}
    assert documents - linked == set()
    assert {'docs/cli.md', 'docs/compare.md', 'docs/noise.md', 'docs/effects.md', 'docs/topics.md', 'docs/bag.md',
            'docs/conventions.md', 'docs/install.md', 'docs/thesis-2004.md'} <= linked


def _heading_anchor(heading: str) -> str:
    """GitHub's anchor for a heading: lower case, punctuation dropped, spaces to hyphens."""
    return re.sub(r'[^\w\- ]', '', heading.strip().lower()).replace(' ', '-')


def _anchors(document: Path) -> set[str]:
    text = re.sub(r'```.*?```', '', document.read_text(), flags=re.DOTALL)
    return {_heading_anchor(match) for match in re.findall(r'^#+ (.+)$', text, flags=re.MULTILINE)}


def _relative_links(document: Path) -> list[str]:
    text = re.sub(r'```.*?```', '', document.read_text(), flags=re.DOTALL)
    return [target for target in re.findall(r'\]\(([^)\s]+)\)', text) if not re.match(r'[a-z]+:', target)]


@pytest.mark.parametrize('document', LINKING_DOCUMENTS, ids=lambda path: path.relative_to(REPO).as_posix())
def test_every_link_resolves(document):
    assert document.is_file()
    for target in _relative_links(document):
        path_part, _, anchor = target.partition('#')
        linked = (document.parent / path_part).resolve() if path_part else document
        assert linked.exists(), f'{document.name}: {target} does not exist'
        if anchor and linked.suffix == '.md':
            assert anchor in _anchors(linked), f'{document.name}: no heading for #{anchor} in {linked.name}'


def test_readme_opens_with_the_two_commands():
    first_block = README.split('```')[1]
    assert 'scripts/run-main' in first_block and 'scripts/run-tests' in first_block
    assert 'scripts/run-tests' in (REPO / '.ci' / 'run').read_text()


def test_the_loop_in_five_commands_parses():
    section = README.split('## The loop in five commands')[1]
    block = section.split('```bash')[1].split('```')[0]
    commands = [part.split('#')[0].strip() for line in block.strip().splitlines() for part in line.split('&&')]
    sofia_commands = [shlex.split(command) for command in commands if command.startswith('sofia ')]
    assert len(sofia_commands) == 5
    parser = build_parser()
    for command in sofia_commands:
        parser.parse_args(command[1:])  # a flag that drifted away exits 2 here


def test_every_documented_verb_exists():
    verbs = build_parser()._subparsers._group_actions[0].choices
    for verb in ('run', 'replay', 'effects', 'demo', 'compare', 'noise', 'model', 'import', 'perturb', 'atlas',
                 'recover'):
        assert verb in verbs and f'sofia {verb}' in README


def test_shipped_params_file_builds_the_graph():
    import yaml

    from sofia_ros.campaigns.graph_params import graph_config_from_parameters

    document = yaml.safe_load((REPO / 'config/alignment.params.yaml').read_text())
    config = graph_config_from_parameters(document['/**']['ros__parameters'])
    assert config.plan.repetitions == 6 and config.tick_ns == DEFAULT_TICK_NS
