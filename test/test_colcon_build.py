"""`colcon build` of the package puts every executable where `ros2 run` looks (lib/sofia_ros)."""

import importlib.metadata
import json
import os
import re
import select
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest

from install_isolation import isolated_env

REPO = Path(__file__).resolve().parents[1]
COLCON = shutil.which('colcon') or str(Path(sys.executable).with_name('colcon'))


def _console_scripts():
    scripts = importlib.metadata.distribution('sofia_ros').entry_points
    return sorted(ep.name for ep in scripts if ep.group == 'console_scripts')


@pytest.fixture(scope='module')
def colcon_install(tmp_path_factory):
    if not Path(COLCON).exists():
        pytest.skip('colcon is not installed (pip install colcon-common-extensions colcon-ros)')
    workspace = tmp_path_factory.mktemp('ws')
    tracked = subprocess.run(
        ['git', 'ls-files', '-co', '--exclude-standard'], cwd=REPO, check=True, capture_output=True, text=True
    ).stdout.split()
    package = workspace / 'src' / 'sofia_ros'
    for relative in tracked:
        source = REPO / relative
        if source.is_file():
            (package / relative).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(source, package / relative)
    result = subprocess.run(
        [COLCON, 'build', '--event-handlers', 'console_direct-'],
        cwd=workspace, capture_output=True, text=True, timeout=240,
    )
    assert result.returncode == 0, result.stdout + result.stderr
    return workspace / 'install' / 'sofia_ros'


def test_every_console_script_lands_in_lib_sofia_ros(colcon_install):
    installed = sorted(path.name for path in (colcon_install / 'lib' / 'sofia_ros').iterdir())
    assert installed == _console_scripts()
    assert 'sofia' in installed


def test_package_is_registered_in_the_ament_index(colcon_install):
    marker = colcon_install / 'share' / 'ament_index' / 'resource_index' / 'packages' / 'sofia_ros'
    assert marker.exists()
    assert (colcon_install / 'share' / 'sofia_ros' / 'package.xml').exists()


def _site_packages(colcon_install):
    return next((colcon_install / 'lib').glob('python3*/site-packages'))


def test_installed_sofia_executable_runs(colcon_install, tmp_path):
    result = subprocess.run(
        [str(colcon_install / 'lib' / 'sofia_ros' / 'sofia'), 'effects', '--json'], cwd=tmp_path,
        capture_output=True, text=True, timeout=60, env=isolated_env(tmp_path / 'isolation', _site_packages(colcon_install)),
    )
    assert result.returncode == 0, result.stderr
    assert any(entry['name'] == 'gyro_misalignment' for entry in json.loads(result.stdout))


def test_an_installed_node_starts_from_the_install_tree(colcon_install, tmp_path):
    env = isolated_env(tmp_path / 'isolation', _site_packages(colcon_install))
    # This test process's reserved domain (conftest): no other worker's live graph can hear the plant.
    env.update(ROS_DOMAIN_ID=os.environ['ROS_DOMAIN_ID'], ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST')
    truth = colcon_install / 'share' / 'sofia_ros' / 'config' / 'truth' / 'nominal.yaml'
    node = subprocess.Popen(
        [str(colcon_install / 'lib' / 'sofia_ros' / 'plant'), '--ros-args', '-p', f'truth_file:={truth}'],
        cwd=tmp_path, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
    )
    lines = []
    try:
        deadline = time.monotonic() + 60.0
        while time.monotonic() < deadline and node.poll() is None:
            # select keeps the timeout honest when the node prints nothing at all.
            if not select.select([node.stdout], [], [], deadline - time.monotonic())[0]:
                break
            line = node.stdout.readline()
            lines.append(line)
            if 'started from' in line:
                break
    finally:
        node.terminate()
        try:
            node.wait(timeout=10)
        except subprocess.TimeoutExpired:
            node.kill()
            node.wait(timeout=10)
        node.stdout.close()
    started = [line for line in lines if 'started from' in line]
    assert started, ''.join(lines)
    package_dir = Path(re.search(r'started from (\S+);', started[0]).group(1))
    assert package_dir == _site_packages(colcon_install) / 'sofia_ros'
