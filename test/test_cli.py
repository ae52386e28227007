"""The `sofia` command as a user runs it: output, exit codes, one-line errors."""

import json
import subprocess
import sys

import pytest

SOFIA = [sys.executable, '-m', 'sofia_ros.cli']


def run_sofia(*args, timeout=120):
    return subprocess.run([*SOFIA, *args], capture_output=True, text=True, timeout=timeout)


def test_effects_lists_every_effect_with_units():
    result = run_sofia('effects')
    assert result.returncode == 0
    assert 'gyro_misalignment' in result.stdout
    assert 'about_los_arcsec = 3590.0 arcsec' in result.stdout


def test_effects_json_is_the_documented_contract():
    result = run_sofia('effects', '--json')
    assert result.returncode == 0
    entries = json.loads(result.stdout)
    names = [entry['name'] for entry in entries]
    assert 'fpi_internal_flexure' in names and 'timestamp_offset' in names


def test_unknown_verb_exits_2_without_traceback():
    result = run_sofia('fly')
    assert result.returncode == 2
    assert 'Traceback' not in result.stderr
    assert "invalid choice: 'fly'" in result.stderr


@pytest.mark.timeout(300)
def test_demo_reproduces_the_thesis_tables():
    result = run_sofia('demo', timeout=280)
    assert result.returncode == 0, result.stderr
    assert 'Traceback' not in result.stderr
    assert 'Table 5.7' in result.stdout and 'Table 6.5' in result.stdout and 'Table D.3' in result.stdout
    assert 'FAIL' not in result.stdout
