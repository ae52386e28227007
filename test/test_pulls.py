"""Honest pulls (issue 25): the atlas' pull (fitted - true) / sigma is computed only where compare gave a sigma, and a
clock offset's fit starts in the basin of its truth.

bench/bench_pulls.py runs the pull table of every visible effect; these tests hold the root causes it found.
"""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest

from sofia_ros.atlas.stats import fit_calibration
from sofia_ros.atlas.task import ROW_FIELDS
from sofia_ros.compare.fit import FreeParameter, _profiled_values


def _row(seed: int, fitted_value: float, fitted_sigma: float | None) -> dict:
    row = {name: None for name in ROW_FIELDS}
    row.update(key=f'tracker_drift|1|alignment|minimal|{seed}', effect='tracker_drift', size=1.0, campaign='alignment',
               variant='minimal', seed=seed, param='linear_px_per_min', true_value=1.4, fitted_value=fitted_value,
               fitted_sigma=fitted_sigma)
    return row


@pytest.mark.parametrize('unconstrained', [math.inf, None], ids=['inf in memory', 'null in JSON'])
def test_a_value_compare_gives_no_sigma_has_no_pull(unconstrained):
    # compare keeps inf in memory (the atlas' rows) where its JSON says null: both mean "the data do not determine
    # it". (fitted - true) / inf counted as a perfect pull of 0 and dragged an off value's mean pull towards 0.
    rng = np.random.default_rng(3)
    honest = [_row(seed, 1.4 + 0.1 * rng.standard_normal(), 0.1) for seed in range(1, 41)]
    off = [_row(seed, 9.0, unconstrained) for seed in range(41, 81)]
    (cell,) = fit_calibration(honest + off)
    assert (cell.count, cell.unconstrained) == (80, 40)
    pulls = [(row['fitted_value'] - 1.4) / 0.1 for row in honest]
    assert cell.pull_mean == pytest.approx(np.mean(pulls)) and cell.pull_std == pytest.approx(np.std(pulls, ddof=1))
    assert cell.median_sigma == pytest.approx(0.1)


def test_a_cell_without_any_sigma_has_no_pull_at_all():
    (cell,) = fit_calibration([_row(seed, 9.0, math.inf) for seed in range(1, 6)])
    assert cell.unconstrained == 5
    assert math.isnan(cell.pull_mean) and math.isnan(cell.pull_std) and math.isnan(cell.median_sigma)


class _StaircaseClock:
    """A fake whitened problem: a telescope that steps 10 arcsec every second and holds in between, seen by rows
    stamped on a clock 1 s late at 0.1, 0.35, 0.6 and 0.85 s into each second: any offset in (0.85, 1.1] s fits them
    exactly. Gauss-Newton from 0 s sees no slope (every row in a hold) and stays there."""

    TRUE_OFFSET_S = 1.0

    def __init__(self):
        self.times_s = np.arange(0.1, 30.0, 0.25)
        self.measured = self._trajectory(self.times_s - self.TRUE_OFFSET_S)
        self.predictor = self
        # one camera, HIPO, whose rows the offset moves
        self.observations = SimpleNamespace(centroids=SimpleNamespace(camera_index=np.zeros(len(self.times_s), int)))

    @staticmethod
    def _trajectory(times_s):
        return 10.0 * np.floor(times_s)

    def row_times_s(self, effects):
        return self.times_s - effects['timestamp_offset']['offset_s']

    def camera_rows(self, camera_index):
        return slice(None)

    def predict_camera_px(self, effects, camera_index, anchors):
        return self._trajectory(self.row_times_s(effects))

    def whiten_rows(self, predicted, rows):
        return (self.measured[rows] - predicted) / 0.3


@pytest.mark.parametrize('start_s', [0.0, 0.15, -2.0])
def test_a_clock_offset_starts_its_fit_at_the_best_of_its_grid(start_s):
    free = (FreeParameter('timestamp_offset', 'offset_s', 's', 1e-3), FreeParameter('gyro_bias', 'el_deg_per_h',
                                                                                     'deg/h', 1e-3))
    effects = {'timestamp_offset': {'offset_s': start_s}, 'gyro_bias': {'el_deg_per_h': 0.2}}
    values = _profiled_values(_StaircaseClock(), effects, free, np.array([start_s, 0.2]), np.zeros((1, 3)))
    assert 0.85 < values[0] <= 1.1 and values[1] == 0.2


def test_a_clock_offset_already_at_its_best_keeps_its_value():
    # a correct model's fit starts where it started: the start wins a tie with the grid
    free = (FreeParameter('timestamp_offset', 'offset_s', 's', 1e-3),)
    values = _profiled_values(_StaircaseClock(), {'timestamp_offset': {'offset_s': 0.9}}, free, np.array([0.9]),
                              np.zeros((1, 3)))
    assert values[0] == 0.9


def test_a_clock_offset_a_previous_fit_converged_is_not_profiled_again():
    # the refits of a comparison start from its final fit: a grid there would cost 121 predictions per fit
    free = (FreeParameter('timestamp_offset', 'offset_s', 's', 1e-3),)
    values = _profiled_values(_StaircaseClock(), {'timestamp_offset': {'offset_s': 0.0}}, free, np.array([0.0]),
                              np.zeros((1, 3)), fitted=frozenset(free))
    assert values[0] == 0.0
