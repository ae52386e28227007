"""design.run.stated_sizes: which of a member's sizes the bag measures (docs/design.md, "How it predicts", step 2)."""

import numpy as np

from sofia_ros.compare.fit import free_parameters
from sofia_ros.design.run import MEASURED_AT_SIGMA, stated_sizes

_CENTRE_X = 'hipo_fiducial_error.center_x_px'
_CENTRE_Y = 'hipo_fiducial_error.center_y_px'


def test_an_estimate_one_or_two_sigmas_from_zero_is_taken_at_the_catalogue_size():
    """Issue 28's hipo-rot-hop set, seed 2: with the imagers' offsets fitted, HIPO's fiducial centre read -331 +- 383
    and -764 +- 400 px against a true -16.2 and -8.8; the first rule (sigma at least the estimate) kept -764 and the
    prediction scaled by it. The rotation the bag measures (-0.378 +- 0.008 deg) keeps its estimate."""
    sizes, assumed = stated_sizes(free_parameters(['hipo_fiducial_error']), np.array([-331.0, -764.0, -0.378]),
                                  np.array([383.0, 400.0, 0.008]))
    np.testing.assert_array_equal(sizes, [-16.2, -8.8, -0.378])
    assert assumed == {_CENTRE_X: {'value': -16.2, 'unit': 'px', 'bag_value': -331.0, 'bag_sigma': 383.0},
                       _CENTRE_Y: {'value': -8.8, 'unit': 'px', 'bag_value': -764.0, 'bag_sigma': 400.0}}


def test_an_estimate_three_sigmas_from_zero_is_measured():
    """At MEASURED_AT_SIGMA sigmas the bag has measured the size, however far from the catalogue's it lies."""
    at_the_bound = np.array([MEASURED_AT_SIGMA * 20.0, -MEASURED_AT_SIGMA * 20.0 - 1.0, -0.36])
    sizes, assumed = stated_sizes(free_parameters(['hipo_fiducial_error']), at_the_bound, np.array([20.0, 20.0, 0.01]))
    np.testing.assert_array_equal(sizes, at_the_bound)
    assert assumed == {}


def test_a_bound_below_the_catalogue_size_keeps_the_estimate():
    """Three sigmas of 4 px (12 px) bound the centre X below its catalogue 16.2 px: the bag says it is small."""
    sizes, assumed = stated_sizes(free_parameters(['hipo_fiducial_error']), np.array([3.0, -8.0, -0.36]),
                                  np.array([4.0, 4.0, 0.01]))
    np.testing.assert_array_equal(sizes, [3.0, -8.8, -0.36])
    assert list(assumed) == [_CENTRE_Y]
