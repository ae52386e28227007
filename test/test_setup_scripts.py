"""scripts/setup-venv: the locks pin the uv it installs with, and a lock without it is refused in one line."""

import re
import shutil
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.parametrize('lock', ['requirements.lock', 'requirements-test.lock'])
def test_each_lock_pins_uv_with_its_hash(lock):
    assert re.search(r'(?m)^uv==[0-9.]+ \\\n    --hash=sha256:[0-9a-f]{64}$', (ROOT / lock).read_text())


@pytest.mark.timeout(60)
def test_a_lock_without_uv_is_refused_before_any_venv_is_made(tmp_path):
    (tmp_path / 'scripts').mkdir()
    shutil.copy(ROOT / 'scripts' / 'setup-venv', tmp_path / 'scripts' / 'setup-venv')
    shutil.copy(ROOT / 'setup.py', tmp_path / 'setup.py')
    lock = (ROOT / 'requirements.lock').read_text()
    (tmp_path / 'requirements.lock').write_text(re.sub(r'(?m)^uv==.*\n.*\n', '', lock))
    done = subprocess.run(['bash', str(tmp_path / 'scripts' / 'setup-venv')], capture_output=True, text=True,
                          timeout=60)
    assert done.returncode == 1 and done.stdout == ''
    assert done.stderr == ('setup: failed: requirements.lock pins no uv (an older lock); '
                           'refresh it with scripts/lock-requirements\n')
    assert not (tmp_path / '.venv').exists()
