"""Honest pulls (issue 25): the atlas' pull (fitted - true) / sigma is computed only where compare gave a sigma.

bench/bench_pulls.py runs the pull table of every visible effect; these tests hold the root causes it found.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from sofia_ros.atlas.stats import fit_calibration
from sofia_ros.atlas.task import ROW_FIELDS


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
