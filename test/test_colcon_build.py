"""`colcon build` of the package puts every executable where `ros2 run` looks (lib/sofia_ros)."""

import importlib.metadata
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

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


def test_installed_sofia_executable_runs(colcon_install):
    site_packages = next((colcon_install / 'lib').glob('python3*/site-packages'))
    env = {**os.environ, 'PYTHONPATH': str(site_packages)}
    result = subprocess.run(
        [str(colcon_install / 'lib' / 'sofia_ros' / 'sofia'), 'effects', '--json'],
        capture_output=True, text=True, timeout=60, env=env,
    )
    assert result.returncode == 0, result.stderr
    assert any(entry['name'] == 'gyro_misalignment' for entry in json.loads(result.stdout))
