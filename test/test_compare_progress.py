"""Progress of `sofia compare` on stderr (sofia_ros.progress): the phases of a compare and the rounds of --search as
lines 'sofia compare: <phase> (<elapsed> s)'; nothing of it on stdout or in --json; --quiet writes none.

The CLI's Progress waits 3 s before its first line; to see every line in a quick test, the tests put a Progress
without that wait (Eager) in its place. Two real compares of a copy of the session's reduced alignment bag (the first
--quiet, writing the observation cache; the second reading it), timings frozen so that their JSON can be compared byte
for byte; --search runs on a stand-in for the comparison.
"""

import contextlib
import io
import shutil
import time
from pathlib import Path

import pytest

from sofia_ros.cli import main
from sofia_ros.compare.cache import CACHE_DIRECTORY
from sofia_ros.progress import Progress

ROOT = Path(__file__).resolve().parents[1]
MODEL = str(ROOT / 'config' / 'model' / 'nominal.yaml')
LINE_PREFIX = 'sofia compare: '


class Eager(Progress):
    """The CLI's Progress writing every line at once."""

    def __init__(self, stream, **options):
        super().__init__(stream, **{**options, 'quiet_for_s': 0.0, 'interval_s': 0.0})


def _run(argv):
    """main(argv) with stdout and stderr captured: (exit code, stdout, stderr)."""
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = main(argv)
    return code, out.getvalue(), err.getvalue()


@pytest.fixture(scope='module')
def runs(campaign_bags, tmp_path_factory):
    """`sofia compare --quiet`, then `sofia compare` with every progress line: {'quiet'|'loud': (code, stdout,
    stderr, JSON bytes)}, the bag and the comparison's CompareResult."""
    import sofia_ros.compare.run as run

    folder = tmp_path_factory.mktemp('progress')
    bag = Path(shutil.copytree(campaign_bags.reduced_alignment(), folder / 'bag',
                               ignore=shutil.ignore_patterns(CACHE_DIRECTORY)))
    results, outcomes = [], {}
    real_compare = run.compare_observations
    with pytest.MonkeyPatch.context() as patch:
        patch.setenv('XDG_CACHE_HOME', str(folder / 'xdg'))
        patch.setattr(time, 'perf_counter', lambda: 0.0)  # the document's timings, so that the JSON compares whole
        patch.setattr('sofia_ros.compare.cli.Progress', Eager)
        patch.setattr(run, 'compare_observations',
                      lambda *args, **options: results.append(real_compare(*args, **options)) or results[-1])
        for name, extra in (('quiet', ['--quiet']), ('loud', [])):
            json_path = folder / f'{name}.json'
            code, out, err = _run(['compare', str(bag), '--model', MODEL, '--json', str(json_path), *extra])
            outcomes[name] = (code, out, err, json_path.read_bytes())
    return outcomes, bag, results[-1]


def test_stdout_and_json_are_the_same_with_and_without_quiet(runs):
    outcomes, _, _ = runs
    assert outcomes['quiet'][0] == outcomes['loud'][0] == 0
    assert outcomes['quiet'][1] == outcomes['loud'][1] and 'verdict: ' in outcomes['loud'][1]
    assert outcomes['quiet'][3] == outcomes['loud'][3]


def test_quiet_leaves_stderr_empty(runs):
    outcomes, _, _ = runs
    assert outcomes['quiet'][2] == ''


def test_the_phases_of_a_compare_go_to_stderr_one_line_each(runs):
    outcomes, _, _ = runs
    lines = outcomes['loud'][2].splitlines()
    assert all(line.startswith(LINE_PREFIX) and line.endswith(' s)') for line in lines), lines
    phases = [line.removeprefix(LINE_PREFIX).rsplit(' (', 1)[0] for line in lines]
    # The second compare reads the observations the first (--quiet) cached; then compare.run's own phases.
    assert phases[:2] == ['reading the bag', 'decoded observations from the cache'], phases
    assert 'residual diagnostics' in phases[2:], phases


@pytest.mark.parametrize('quiet', [False, True], ids=['progress', 'quiet'])
def test_the_search_rounds_go_through_the_same_progress_and_quiet_silences_them(runs, monkeypatch, quiet):
    outcomes, bag, result = runs

    def compare(observations, model, **options):
        options['progress'].phase('comparing (stand-in)')
        return result

    monkeypatch.setattr('sofia_ros.compare.run.compare_observations', compare)
    monkeypatch.setattr('sofia_ros.compare.cli.Progress', Eager)
    monkeypatch.setenv('XDG_CACHE_HOME', str(bag.parent / 'xdg'))
    code, out, err = _run(['compare', str(bag), '--model', MODEL, '--search', '--search-rounds', '1',
                           *(['--quiet'] if quiet else [])])
    assert code == 0 and out.startswith(outcomes['loud'][1]) and 'search: the model the data ask for' in out
    if quiet:
        assert err == ''
    else:
        phases = [line.removeprefix(LINE_PREFIX).rsplit(' (', 1)[0] for line in err.splitlines()]
        assert phases == ['reading the bag', 'decoded observations from the cache',
                          'search: round 1/1, the model given', 'comparing (stand-in)',
                          'search: ends after round 1: no comparison suggests a step not yet compared'], err
