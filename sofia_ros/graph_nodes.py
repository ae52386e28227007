"""Every node of the campaign graph and the executable that runs it, in one place.

Standard library only: setup.py reads this file for the console scripts before the package is
installed. The cores are built by ``sim.graph.build_core``; the executables are
``nodes.executables``; ``test/test_registries.py`` fails when a node is missing from either.
"""

from __future__ import annotations

__all__ = ['CAMERAS', 'IMAGERS', 'NODE_NAMES', 'SEEDED_NODES', 'EXECUTABLES', 'executable_of']

#: The four cameras, HIPO first (the reference the imagers are measured against), in graph order.
CAMERAS = ('hipo', 'fpi', 'ffi', 'wfi')
#: The science imagers (every camera but HIPO).
IMAGERS = CAMERAS[1:]
#: Every node of the alignment graph, in a fixed order (seeds are drawn in this order).
NODE_NAMES = ('clock', 'plant', 'gyro_box', *CAMERAS, 'tascu', 'calibration')
#: The nodes that draw their own seed from the run seed, in the order they draw it.
SEEDED_NODES = ('gyro_box', *CAMERAS)
#: executable (``ros2 run sofia_ros <executable>``) -> the nodes it runs: ``imager`` runs one imager,
#: named by its ``camera`` parameter; the recorder is no core of the graph but a node of every run.
EXECUTABLES = {
    'clock': ('clock',), 'plant': ('plant',), 'gyro_box': ('gyro_box',), 'imager': IMAGERS, 'hipo': ('hipo',),
    'tascu': ('tascu',), 'calibration': ('calibration',), 'recorder': ('recorder',),
}


def executable_of(node: str) -> str:
    """The executable that runs ``node``; KeyError for a node no executable runs."""
    return next(executable for executable, nodes in EXECUTABLES.items() if node in nodes)
