"""A wheel of the package holds every module, and every console script imports from it alone."""

from __future__ import annotations

import configparser
import json
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

from install_isolation import isolated_env

REPO = Path(__file__).resolve().parents[1]

# Imports each console script's target from the install, then reports where every sofia_ros module came from.
IMPORT_SCRIPTS = '''
import importlib, json, sys
targets = json.loads(sys.argv[1])
for target in targets:
    module_name, _, attribute = target.partition(':')
    getattr(importlib.import_module(module_name), attribute)
print(json.dumps({name: getattr(module, '__file__', None) for name, module in sys.modules.items()
                  if name == 'sofia_ros' or name.startswith('sofia_ros.')}))
'''


def _tracked_modules():
    listed = subprocess.run(['git', 'ls-files', '-co', '--exclude-standard', 'sofia_ros'], cwd=REPO, check=True, capture_output=True,
                            text=True).stdout.split()
    return sorted(name for name in listed if name.endswith('.py'))


@pytest.fixture(scope='module')
def wheel(tmp_path_factory):
    """The wheel built from the tracked files of the checkout (a copy, so the checkout gets no build/)."""
    root = tmp_path_factory.mktemp('wheel')
    source = root / 'src'
    for relative in subprocess.run(['git', 'ls-files', '-co', '--exclude-standard'], cwd=REPO, check=True,
                                   capture_output=True, text=True).stdout.split():
        if (REPO / relative).is_file():
            (source / relative).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(REPO / relative, source / relative)
    result = subprocess.run(
        [sys.executable, '-m', 'pip', 'wheel', '--no-deps', '--no-build-isolation', '--wheel-dir', str(root / 'dist'),
         str(source)], capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stdout + result.stderr
    (path,) = (root / 'dist').glob('sofia_ros-*.whl')
    return path


def test_the_wheel_holds_every_module_of_the_package(wheel):
    with zipfile.ZipFile(wheel) as archive:
        packed = sorted(name for name in archive.namelist() if name.endswith('.py'))
    assert packed == _tracked_modules()


def test_every_console_script_imports_from_the_installed_wheel_alone(wheel, tmp_path):
    target = tmp_path / 'target'
    result = subprocess.run([sys.executable, '-m', 'pip', 'install', '--no-deps', '--target', str(target), str(wheel)],
                            capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stdout + result.stderr
    (entry_points,) = target.glob('sofia_ros-*.dist-info/entry_points.txt')
    parser = configparser.ConfigParser()
    parser.read(entry_points)
    targets = dict(parser['console_scripts'])
    assert {'sofia', 'clock', 'plant', 'gyro_box', 'imager', 'hipo', 'tascu', 'calibration', 'recorder'} <= set(targets)
    outside = tmp_path / 'elsewhere'
    outside.mkdir()
    result = subprocess.run([sys.executable, '-c', IMPORT_SCRIPTS, json.dumps(sorted(set(targets.values())))],
                            cwd=outside, env=isolated_env(tmp_path / 'isolation', target), capture_output=True,
                            text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    loaded = json.loads(result.stdout)
    assert 'sofia_ros.sim.runner' in loaded
    assert 'sofia_ros.nodes.executables' in loaded
    elsewhere = {name: path for name, path in loaded.items() if not Path(path).is_relative_to(target)}
    assert elsewhere == {}


def test_the_isolation_hides_the_editable_checkout(tmp_path):
    # Without an install on the path, sofia_ros must not be importable at all: proof the checkout is out of the way.
    empty = tmp_path / 'empty'
    empty.mkdir()
    result = subprocess.run([sys.executable, '-c', 'import sofia_ros'], cwd=tmp_path,
                            env=isolated_env(tmp_path / 'isolation', empty), capture_output=True, text=True, timeout=60)
    assert result.returncode == 1
    assert "No module named 'sofia_ros'" in result.stderr
