"""The package's import graph, read from the source (every import, also those inside functions).

Arrows point one way: the entry points (the ``sofia`` CLI, the node executables) -> atlas (which runs
campaigns and compares them) -> campaigns -> nodes -> sim -> science core; the offline tools (compare, noise, perturb, measurements, analysis,
bag) -> science core and bag, never sim/, nodes/ or campaigns/. ``python test/test_import_graph.py``
prints the graph between the packages.
"""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / 'sofia_ros'
#: modules a user or ``ros2 run`` starts (the ``sofia`` verbs' front ends, the node executables); they sit
#: on top and may import any layer
ENTRY_POINTS = {'sofia_ros.cli', 'sofia_ros.nodes.executables', *(
    '.'.join(path.relative_to(PACKAGE.parent).with_suffix('').parts) for path in PACKAGE.glob('*/*cli.py'))}
OFFLINE_TOOLS = ('analysis', 'bag', 'compare', 'design', 'measurements', 'noise', 'perturb')
#: the layers above the science core, top first: a layer imports only the ones after it
GRAPH_LAYERS = ('atlas', 'campaigns', 'nodes', 'sim')


def module_name(path):
    parts = path.relative_to(PACKAGE.parent).with_suffix('').parts
    return '.'.join(parts[:-1] if parts[-1] == '__init__' else parts)


def imports_of(path):
    """The sofia_ros modules one file imports (``from sofia_ros import x`` counts as sofia_ros.x when x is one)."""
    name = module_name(path)
    package = name if path.name == '__init__.py' else name.rpartition('.')[0]
    found = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ''
            if node.level:
                anchor = package.split('.')[:len(package.split('.')) - node.level + 1]
                base = '.'.join([*anchor, *([base] if base else [])])
            found.add(base)
            found.update(f'{base}.{alias.name}' for alias in node.names)
    return {module for module in found if module in MODULES and module != name}


MODULES = {module_name(path): path for path in PACKAGE.rglob('*.py')}
GRAPH = {module: imports_of(path) for module, path in MODULES.items()}


def group(module):
    """The package a module belongs to ('sofia_ros.compare.fit' -> 'compare'); top-level modules are 'core'."""
    parts = module.split('.')
    return parts[1] if len(parts) > 2 or (len(parts) == 2 and (PACKAGE / parts[1]).is_dir()) else 'core'


def package_graph():
    """group -> the groups it imports (entry points shown as their own node)."""
    edges = {}
    for module, targets in GRAPH.items():
        source = module.removeprefix('sofia_ros.') if module in ENTRY_POINTS else group(module)
        for target in targets:
            if group(target) != group(module) or module in ENTRY_POINTS:
                edges.setdefault(source, set()).add(group(target))
    return edges


def cycles(graph):
    """Strongly connected components of more than one module (Tarjan), each sorted."""
    index, low, stack, on_stack, found = {}, {}, [], set(), []

    def visit(node):
        index[node] = low[node] = len(index)
        stack.append(node)
        on_stack.add(node)
        for target in graph.get(node, ()):
            if target not in index:
                visit(target)
                low[node] = min(low[node], low[target])
            elif target in on_stack:
                low[node] = min(low[node], index[target])
        if low[node] == index[node]:
            component = []
            while True:
                member = stack.pop()
                on_stack.discard(member)
                component.append(member)
                if member == node:
                    break
            if len(component) > 1:
                found.append(sorted(component))

    sys.setrecursionlimit(max(sys.getrecursionlimit(), 10 * len(graph)))
    for node in graph:
        if node not in index:
            visit(node)
    return found


def offending(sources, forbidden):
    """(module, imported module) for every import from a module in ``sources`` into a group in ``forbidden``."""
    return sorted((module, target) for module, targets in GRAPH.items()
                  if group(module) in sources and module not in ENTRY_POINTS
                  for target in targets if group(target) in forbidden)


def test_the_graph_covers_every_module():
    assert len(MODULES) > 100 and all(GRAPH[module] <= set(MODULES) for module in MODULES)
    assert 'sofia_ros.sim.graph' in GRAPH['sofia_ros.campaigns.alignment']  # the parser sees imports


def test_no_import_cycle_below_the_entry_points():
    below = {module: targets for module, targets in GRAPH.items() if module not in ENTRY_POINTS}
    assert cycles(below) == []


def test_offline_tools_import_no_node_graph_code():
    assert offending(OFFLINE_TOOLS, set(GRAPH_LAYERS)) == []


def test_graph_layers_import_only_downwards():
    for position, layer in enumerate(GRAPH_LAYERS):
        above = set(GRAPH_LAYERS[:position])
        assert offending({layer}, above) == [], f'{layer} imports a layer above it'


def test_the_science_core_imports_neither_the_graph_nor_the_tools():
    layers = {group(module) for module in GRAPH} - set(GRAPH_LAYERS) - set(OFFLINE_TOOLS)
    assert offending(layers, {*GRAPH_LAYERS, *OFFLINE_TOOLS} - {'bag'}) == []


#: What a node process imports on its way to "started" that it does not need to start: the bag's type store and
#: reader (rosbags, mcap: 0.2-0.4 CPU-s) and scipy.optimize (0.1-0.3 CPU-s), in each of a graph's eleven processes.
NODE_PATH_HEAVY = ('rosbags', 'mcap', 'scipy.optimize')


@pytest.mark.parametrize('module', ['sofia_ros.messages', 'sofia_ros.bag.timebase', 'sofia_ros.calibration'])
def test_a_node_path_module_loads_no_bag_reader_or_optimizer(module):
    # A fresh interpreter: this session has long imported both.
    probe = (f'import sys, {module}; '
             f'print(*sorted(name for name in {NODE_PATH_HEAVY!r} if name in sys.modules))')
    loaded = subprocess.run([sys.executable, '-c', probe], capture_output=True, text=True, check=True,
                            cwd=PACKAGE.parent, timeout=120).stdout.split()
    assert loaded == [], f'importing {module} loads {loaded}'


#: A node process needs the type store (it decodes its DDS inputs with it), not the bag's files or an optimizer.
NODE_PROCESS_HEAVY = ('mcap', 'rosbags.highlevel', 'rosbags.rosbag2', 'scipy.optimize')


def test_a_node_process_loads_no_bag_file_code_or_optimizer():
    # What executables' _build imports for any node: the graph, its cores, the clock and the campaigns' documents.
    modules = ('sofia_ros.nodes.executables', 'sofia_ros.sim.graph', 'sofia_ros.nodes.shell',
               'sofia_ros.nodes.clock_node', 'sofia_ros.campaigns.recording')
    probe = (f'import sys; import {", ".join(modules)}; '
             f'print(*sorted(name for name in {NODE_PROCESS_HEAVY!r} if name in sys.modules))')
    loaded = subprocess.run([sys.executable, '-c', probe], capture_output=True, text=True, check=True,
                            cwd=PACKAGE.parent, timeout=120).stdout.split()
    assert loaded == [], f'a node process loads {loaded}'


if __name__ == '__main__':
    for source, targets in sorted(package_graph().items()):
        print(f'{source:18} -> {", ".join(sorted(targets))}')
