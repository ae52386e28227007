"""Test isolation and shared campaign bags.

DDS stays on this machine, in a domain of its own per test process: one no sofia run holds at the
start (nodes.domain's lock files) and that no other test process on this machine has reserved (a
lock of its own, held for the session). So an xdist worker never shares its domain with another
worker, nor with a sofia run or another test session (with this conftest) on the machine.

Campaign bags that several tests read are recorded once per session (:class:`CampaignBags`), also
across xdist workers: the first process to ask records, the others wait for it and read the bag.
"""

import fcntl
import os
import random
import tempfile
from pathlib import Path

from sofia_ros.errors import DomainBusyError
from sofia_ros.nodes.domain import DOMAIN_IDS, claim_ros_domain, domain_lock_directory, release_ros_domain


def _reserve_test_domain(rng=random.SystemRandom()):
    """A domain free of sofia runs, reserved for this process's session by a lock no run uses; its id."""
    candidates = list(DOMAIN_IDS)
    rng.shuffle(candidates)
    for domain_id in candidates:
        path = domain_lock_directory() / f'sofia_ros-test-domain-{domain_id}.lock'
        try:
            descriptor = os.open(path, os.O_RDWR | os.O_CREAT, 0o666)
        except PermissionError:
            continue
        try:
            fcntl.flock(descriptor, fcntl.LOCK_EX | fcntl.LOCK_NB)
            release_ros_domain(claim_ros_domain({'ROS_DOMAIN_ID': str(domain_id)}), {})
        except (BlockingIOError, DomainBusyError):
            os.close(descriptor)
            continue
        _RESERVATION.append(descriptor)  # held until the process exits
        return domain_id
    raise DomainBusyError(f'every ROS domain {DOMAIN_IDS.start}-{DOMAIN_IDS.stop - 1} is reserved by tests or runs')


_RESERVATION = []
os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
os.environ['ROS_DOMAIN_ID'] = str(_reserve_test_domain())


import pytest  # noqa: E402  (the DDS environment must be set before anything imports rclpy)

ROOT = Path(__file__).resolve().parents[1]


def record_reduced_alignment(bag_path, *, seed, effect=None, scenario=None):
    """A reduced alignment campaign (2 repetitions, 1 verification) in direct mode: nominal truth plus ``effect``
    (a name, or names joined by '+')."""
    import yaml

    from sofia_ros.campaigns.alignment import run_alignment
    from sofia_ros.config import parse_effect_config
    from sofia_ros.sim.calibration import AlignmentPlan

    document = yaml.safe_load((ROOT / 'config' / 'truth' / 'nominal.yaml').read_text())
    # One effect by name, or several joined by '+': the truth of a loop with competing explanations.
    for name in (effect or '').split('+'):
        if name:
            document['effects'][name] = {}
    if scenario:
        document['scenario'] = scenario
    truth = parse_effect_config(yaml.safe_dump(document), f'nominal + {effect}')
    run_alignment(truth, seed=seed, bag_path=bag_path, mode='direct',
                  plan=AlignmentPlan(repetitions=2, verification_repetitions=1))
    return bag_path


class CampaignBags:
    """Bags recorded once per session into one folder that every xdist worker of the session sees.

    A bag is recorded under an exclusive lock of its own; a marker file says it is complete. A
    recording that failed leaves no marker and no folder, so the next test that asks tries again
    (and fails with the real error).
    """

    def __init__(self, folder):
        self.folder = Path(folder)
        self.folder.mkdir(parents=True, exist_ok=True)

    def get(self, key, record):
        """The bag ``key``; ``record(path)`` writes it there when no process of the session has yet."""
        import shutil

        bag = self.folder / key
        done = self.folder / f'{key}.done'
        with open(self.folder / f'{key}.lock', 'w') as lock:
            fcntl.flock(lock, fcntl.LOCK_EX)
            if not done.exists():
                shutil.rmtree(bag, ignore_errors=True)
                record(bag)
                done.touch()
        return bag

    def reduced_alignment(self, *, seed=3, effect=None, scenario=None):
        """A bag of :func:`record_reduced_alignment`, once per session."""
        key = '-'.join(['alignment', f'seed{seed}', effect or 'nominal',
                        *(f'{name}={value}' for name, value in sorted((scenario or {}).items()))])
        return self.get(key, lambda path: record_reduced_alignment(path, seed=seed, effect=effect, scenario=scenario))


def _xdist_worker():
    return os.environ.get('PYTEST_XDIST_WORKER')


@pytest.fixture
def private_tmp(tmp_path, monkeypatch):
    """A temporary directory of this test alone (tempfile's, and its subprocesses' TMPDIR): what a run leaves there
    (the launcher's sofia_graph_* node logs) is its own, not a live graph's of the other xdist worker."""
    folder = tmp_path / 'tmp'
    folder.mkdir()
    monkeypatch.setenv('TMPDIR', str(folder))
    monkeypatch.setattr(tempfile, 'tempdir', str(folder))
    return folder


@pytest.fixture(scope='session')
def campaign_bags(tmp_path_factory):
    """The session's shared campaign bags (under xdist, the workers' base folders share a parent)."""
    base = tmp_path_factory.getbasetemp()
    return CampaignBags((base.parent if _xdist_worker() else base) / 'campaign_bags')


# --- xdist (scripts/run-tests runs the suite with `-n 2 --dist loadscope --no-loadscope-reorder`) ------
#
# A module is one unit of work (its module fixtures run once) unless it is listed in SPREAD: those
# modules' expensive bags come from the session's CampaignBags, so their tests go to whichever worker
# is free; a long test that needs no module fixture may be a unit of its own (ALONE). The DDS modules
# share two units (one, 1182 s, was a fifth of the work), so at most two live graphs start at once. Units are
# handed out longest first (MEASURED_S), so that a long one never starts last and ends the run alone;
# the others follow in collection order. A worker is given its next unit when one test of its current
# unit is left (xdist waits for two: the next unit then also waited behind the second last test,
# minutes for the atlas cluster's). The units are this file's own scheduler's scopes
# (pytest_xdist_make_scheduler), not xdist_group marks: loadgroup reads those from mutated node ids,
# which pytest 9.2 no longer allows (pytest-xdist issue 1386).

#: modules whose tests are handed out one by one
SPREAD = frozenset({'test_compare', 'test_discovery', 'test_fuzz_inputs'})
#: long tests that use none of their module's module fixtures, handed out on their own ('module::test')
ALONE = frozenset({
    'test_star_hop::test_tracker_drift_sinusoid_is_recovered_from_a_hold_of_one_period',
    'test_star_hop::test_fpi_internal_flexure_is_named_and_measures_about_1_1_arcsec_over_23_to_60_deg',
})
#: modules that share a unit of work with others (module -> unit)
UNITS = {'test_live_graph': 'dds', 'test_mode_bags': 'dds',
         'test_run_signals': 'dds-runs', 'test_star_hop_processes': 'dds-runs', 'test_full_disk': 'dds-runs'}
#: seconds of the longest units (a SPREAD module: all its tests, or a 'module::test' entry: each of its
#: cases, its longest), summed from `--durations=0` of a whole CI run (a fresh clone of 9beae0a, quiet, -n 3 on
#: 2 cores, 645 s: /tmp/dev/s20/ci20.log), set-up, call and tear-down; the shared campaign bags recorded where
#: first asked for
MEASURED_S = {
    'dds-runs': 283,  # test_full_disk 136 (its set-up records the shared reduced bag: 73), test_run_signals 108,
                      # test_star_hop_processes 39
    'dds': 214,  # test_live_graph 205, test_mode_bags 9
    'test_atlas_cluster': 111, 'test_search_loop': 63, 'test_alignment_campaign': 61,
    'test_star_hop': 59,  # 88 with its two ALONE tests
    'test_perturb': 58, 'test_noise_report': 50,
    # each case records its own bag and compares it: 23-45 s
    'test_compare::test_hidden_effect_is_the_top_candidate_within_three_sigma_and_brings_the_floor': 45,
    'test_csv_import': 33,
    'test_compare::test_swapped_calibrations_at_constant_temperature_are_degenerate_with_a_scale_factor': 30,
    'test_effect_plugins': 27, 'test_atlas_multi_effect': 24, 'test_observation_cache': 24,
    'test_atlas_refusals': 20,
    'test_compare::test_cli_loop_compare_add_compare_shows_the_error_falling': 20,
    'test_plan_temperature': 18,
    'test_star_hop::test_tracker_drift_sinusoid_is_recovered_from_a_hold_of_one_period': 17,
    'test_gyro_noise': 16, 'test_bag_refusals': 16, 'test_input_validation': 15, 'test_plan_files': 15,
    'test_noise_loop': 14, 'test_noise_cli': 14, 'test_launch_waits': 14,
    'test_star_hop::test_fpi_internal_flexure_is_named_and_measures_about_1_1_arcsec_over_23_to_60_deg': 13,
    'test_spectra': 13, 'test_accuracy': 12,
    'test_discovery::test_an_out_of_catalogue_shape_is_flagged_named_not_falsely_closed_and_explained_by_a_plugin': 10,
}
#: units handed out first, longest first; every other unit follows in collection order
FIRST = tuple(sorted(MEASURED_S, key=MEASURED_S.get, reverse=True))


def _module_of(nodeid):
    return nodeid.split('::', 1)[0].rsplit('/', 1)[-1].removesuffix('.py')


def _function_of(nodeid):
    """'module::test' of a test id, without its parameters: the MEASURED_S key of a SPREAD module's test."""
    return f"{_module_of(nodeid)}::{nodeid.split('::', 1)[-1].split('[', 1)[0]}"


def _unit_of(nodeid):
    """The unit of work of a test: its module's, the one it shares (UNITS), or its own (SPREAD, ALONE)."""
    module = _module_of(nodeid)
    if module in SPREAD:
        return nodeid
    alone = f"{module}::{nodeid.split('::', 1)[-1]}"
    if alone in ALONE:
        return alone
    return UNITS.get(module, module)


def pytest_xdist_make_scheduler(config, log):
    """With --dist loadscope, this file's units (else xdist's own scheduler)."""
    if config.getoption('dist') != 'loadscope':
        return None
    from xdist.scheduler import LoadScopeScheduling

    class UnitScheduling(LoadScopeScheduling):
        def _split_scope(self, nodeid):
            return _unit_of(nodeid)

        def _reschedule(self, node):
            # A worker runs a test once it has been sent the next one: with two left it needs no unit yet.
            if self.workqueue and not node.shutting_down and self._pending_of(self.assigned_work[node]) > 1:
                return
            super()._reschedule(node)

    return UnitScheduling(config, log)


def pytest_collection_modifyitems(config, items):
    if _xdist_worker():
        rank = {unit: index for index, unit in enumerate(FIRST)}

        def order(item):
            # a SPREAD module's tests are units of their own, ranked by their test's entry, else their module's
            nodeid = item.nodeid
            return rank.get(_unit_of(nodeid), rank.get(_function_of(nodeid), rank.get(_module_of(nodeid), len(rank))))

        items.sort(key=order)  # stable otherwise
