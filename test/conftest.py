"""Test isolation: DDS stays on this machine, in a random domain of its own per session.

The domain is one no sofia run holds at the start (nodes.domain's lock files), so a session
does not collide with another engineer's tests or runs on the same machine.
"""

import os
import random

from sofia_ros.nodes.domain import claim_ros_domain, release_ros_domain

os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
_probe = claim_ros_domain({}, rng=random.SystemRandom())
release_ros_domain(_probe, {})
os.environ['ROS_DOMAIN_ID'] = str(_probe.domain_id)


import pytest  # noqa: E402  (the DDS environment must be set before anything imports rclpy)


def record_reduced_alignment(bag_path, *, seed, effect=None, scenario=None):
    """A reduced alignment campaign (2 repetitions, 1 verification) in direct mode: nominal truth plus one effect."""
    from pathlib import Path

    import yaml

    from sofia_ros.campaigns.alignment import run_alignment
    from sofia_ros.config import parse_effect_config
    from sofia_ros.sim.calibration import AlignmentPlan

    document = yaml.safe_load((Path(__file__).resolve().parents[1] / 'config' / 'truth' / 'nominal.yaml').read_text())
    if effect:
        document['effects'][effect] = {}
    if scenario:
        document['scenario'] = scenario
    truth = parse_effect_config(yaml.safe_dump(document), f'nominal + {effect}')
    run_alignment(truth, seed=seed, bag_path=bag_path, mode='direct',
                  plan=AlignmentPlan(repetitions=2, verification_repetitions=1))
    return bag_path


@pytest.fixture(scope='session')
def nominal_alignment_bags(tmp_path_factory):
    """Untouched reduced alignment bags of the nominal truth, seeds 3-7, recorded once per session (two at a time)."""
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    folder = tmp_path_factory.mktemp('nominal_alignment')
    seeds = (3, 4, 5, 6, 7)
    # Spawned, not forked: the test process may hold rclpy's threads.
    with ProcessPoolExecutor(max_workers=2, mp_context=multiprocessing.get_context('spawn')) as pool:
        futures = {seed: pool.submit(record_reduced_alignment, folder / f'seed{seed}', seed=seed) for seed in seeds}
        return {seed: future.result() for seed, future in futures.items()}
