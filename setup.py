"""ament_python package setup: `colcon build` puts executables in lib/sofia_ros, pip in bin/."""

import runpy
from glob import glob
from pathlib import Path

from setuptools import find_packages, setup

PACKAGE_NAME = 'sofia_ros'

# One executable per node (``ros2 run sofia_ros <name>``) plus the ``sofia`` command; the node
# executables are listed once, in sofia_ros/graph_nodes.py (standard library only, so it runs here).
GRAPH_NODES = runpy.run_path(str(Path(__file__).resolve().parent / PACKAGE_NAME / 'graph_nodes.py'))
NODE_EXECUTABLES = {
    'sofia': 'sofia_ros.cli:main',
    **{name: f'sofia_ros.nodes.executables:{name}' for name in GRAPH_NODES['EXECUTABLES']},
}


def config_data_files():
    """Install config/ (and its truth/ and model/ presets) under share/sofia_ros."""
    files = []
    for folder in ('config', 'config/truth', 'config/model', 'config/plans'):
        matches = sorted(glob(f'{folder}/*.yaml'))
        if matches:
            files.append((f'share/{PACKAGE_NAME}/{folder}', matches))
    return files


setup(
    name=PACKAGE_NAME,
    version='0.1.0',
    packages=find_packages(exclude=['test', 'test.*', 'bench']),
    data_files=[
        ('share/ament_index/resource_index/packages', [f'resource/{PACKAGE_NAME}']),
        (f'share/{PACKAGE_NAME}', ['package.xml']),
        *config_data_files(),
    ],
    install_requires=['setuptools'],
    zip_safe=False,
    maintainer='sofia_ros developers',
    maintainer_email='dev@sofia-ros.local',
    description='SOFIA pointing-control emulation and calibration analysis on ROS 2',
    license='MIT',
    entry_points={
        'console_scripts': [f'{name} = {target}' for name, target in NODE_EXECUTABLES.items()],
    },
)
