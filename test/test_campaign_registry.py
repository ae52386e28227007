"""The campaign registry: every campaign is listed once, runs through its record, and bad names are one line."""

import pytest

from sofia_ros.campaigns import graph_params
from sofia_ros.campaigns.registry import CAMPAIGNS, campaign_named
from sofia_ros.errors import ConfigError
from sofia_ros.sim.calibration import AlignmentPlan
from sofia_ros.sim.star_hop import StarHopPlan


def test_the_registry_lists_each_campaign_the_cli_runs():
    assert list(CAMPAIGNS) == ['alignment', 'star-hop', 'gyro-stability']
    assert set(graph_params.CAMPAIGNS) == {'alignment', 'star-hop'}


def test_reduced_variants_are_the_plans_the_tests_fly():
    assert campaign_named('alignment').plan('reduced') == AlignmentPlan(repetitions=2, verification_repetitions=1)
    reduced_hop = campaign_named('star-hop').plan('reduced')
    assert isinstance(reduced_hop, StarHopPlan) and len(reduced_hop.observations) == 4
    assert campaign_named('alignment').plan('reduced', drift_track_s=10.0).drift_track_s == 10.0


def test_a_plan_names_its_campaign():
    assert StarHopPlan().campaign == 'star-hop' and AlignmentPlan().campaign == 'alignment'


def test_unknown_campaign_and_variant_are_one_line():
    with pytest.raises(ConfigError, match="unknown campaign 'polar'; available: alignment, star-hop, gyro-stability"):
        campaign_named('polar')
    with pytest.raises(ConfigError, match="no variant 'tiny'; use one of full, reduced"):
        campaign_named('alignment').plan('tiny')
    with pytest.raises(ConfigError, match='gyro-stability campaign has no plan'):
        campaign_named('gyro-stability').plan()
