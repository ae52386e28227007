"""The library of plan elements `sofia design` chooses from, and the choice (docs/design.md).

Each element is one plan element of docs/plans.md (the only maneuvers the calibration node can
fly): Table 3.4's moves at another elevation, LOS rotations, holds at a LOS angle, a longer
hold. Temperature is not among them: no plan can command it (docs/plans.md). The library is
flown once, on the nominal truth after the minimal alignment, to learn each element's geometry
and flight time; an element is then summarized by its profiled information.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass
from typing import Mapping, Sequence

import numpy as np

from sofia_ros.design.separation import Information, expected_delta_bic, noncentrality, sigma_of
from sofia_ros.errors import InvalidArgumentError

__all__ = ['ALIGNMENT_LIBRARY', 'Choice', 'Element', 'Hypothesis', 'Prediction', 'choose_elements', 'predict',
           'smallest_flight_s']


@dataclass(frozen=True)
class Element:
    """One plan element of the library: a short name and its plan-file mapping."""

    name: str
    document: Mapping


#: Elevations and LOS angles inside the door drive's 20-60 deg and the fine drive's +-3 deg (docs/plans.md).
ALIGNMENT_LIBRARY = (
    Element('maneuvers at 25 deg', {'maneuvers': {'elevation_deg': 25.0, 'repetitions': 2}}),
    Element('maneuvers at 40 deg', {'maneuvers': {'elevation_deg': 40.0, 'repetitions': 2}}),
    Element('maneuvers at 55 deg', {'maneuvers': {'elevation_deg': 55.0, 'repetitions': 2}}),
    Element('LOS rotations -2.5..+2.5 deg at 40 deg',
            {'los_rotations': {'angles_deg': [-2.5, 0.0, 2.5], 'elevation_deg': 40.0}}),
    Element('hold 60 s at LOS +2.5 deg', {'hold': {'duration_s': 60.0, 'los_deg': 2.5, 'elevation_deg': 40.0}}),
    Element('hold 60 s at LOS -2.5 deg', {'hold': {'duration_s': 60.0, 'los_deg': -2.5, 'elevation_deg': 40.0}}),
    Element('hold 180 s at LOS 0 deg', {'hold': {'duration_s': 180.0, 'los_deg': 0.0, 'elevation_deg': 40.0}}),
)


@dataclass(frozen=True)
class Hypothesis:
    """One member of the competing set: its name, fitted labels and size (the comparison's linearized fit)."""

    name: str
    labels: tuple
    values: np.ndarray


@dataclass(frozen=True)
class Prediction:
    """Expected delta-BIC for each direction ('A true' -> 'B' loses by), and the members' sigmas."""

    separation: dict
    sigma: dict
    rows: int

    @property
    def weakest(self) -> float:
        """The smaller of the two directions: the separation whichever member is true."""
        return min(self.separation.values())


def predict(information: Information, shared: Sequence[str], first: Hypothesis, second: Hypothesis,
            variance: float) -> Prediction:
    """The expected delta-BIC each way over ``information``, and each member's sigmas fitted with the model's terms.

    Args:
        information: the data's profiled information (old bag plus elements).
        shared: the model's fitted labels.
        first: member A.
        second: member B.
        variance: s^2 of the whitened residuals with the best member fitted.

    Returns:
        The Prediction; separation keys are the true member's name.
    """
    separation, sigma = {}, {}
    for true, rival in ((first, second), (second, first)):
        value = noncentrality(information, true.labels, true.values, rival.labels, shared)
        separation[true.name] = expected_delta_bic(value, len(true.labels), len(rival.labels), information.rows,
                                                   variance)
        fitted = [*shared, *true.labels]
        sigma[true.name] = dict(zip(fitted, sigma_of(information, fitted, variance).tolist()))
    return Prediction(separation, sigma, information.rows)


@dataclass(frozen=True)
class Choice:
    """The elements chosen (library indices), their flight time, the prediction, and whether it reaches the target."""

    indices: tuple
    flight_s: float
    prediction: Prediction
    reached: bool


def smallest_flight_s(flight_s: Sequence[float]) -> float:
    """The shortest element's flight time."""
    return float(min(flight_s))


def choose_elements(base: Information, elements: Sequence[Information], flight_s: Sequence[float],
                    shared: Sequence[str], first: Hypothesis, second: Hypothesis, variance: float, *,
                    target: float, budget_s: float) -> Choice:
    """The fewest elements (then the shortest flight) whose expected delta-BIC reaches ``target`` both ways.

    Every subset within the budget is tried (a library of a few elements: at most 2^n small
    matrix sums). When none reaches the target, the subset within the budget with the largest
    weakest separation is returned, marked not reached.

    Args:
        base: the old bag's information.
        elements: each library element's information (zero gradient).
        flight_s: each element's flight time.
        shared: the model's fitted labels.
        first: member A.
        second: member B.
        variance: s^2 of the whitened residuals.
        target: the delta-BIC to reach in both directions.
        budget_s: the largest flight time allowed.

    Returns:
        The Choice.

    Raises:
        InvalidArgumentError: the budget is below the shortest element.
    """
    if budget_s < smallest_flight_s(flight_s):
        raise InvalidArgumentError(f'a budget of {budget_s:.0f} s is below the shortest element '
                                   f'({smallest_flight_s(flight_s):.0f} s); raise --budget-s')
    best = None
    for size in range(1, len(elements) + 1):
        subsets = sorted(itertools.combinations(range(len(elements)), size),
                         key=lambda subset: sum(flight_s[index] for index in subset))
        for subset in subsets:
            seconds = float(sum(flight_s[index] for index in subset))
            if seconds > budget_s:
                break
            information = base
            for index in subset:
                information = information + elements[index]
            prediction = predict(information, shared, first, second, variance)
            choice = Choice(subset, seconds, prediction, prediction.weakest >= target)
            if choice.reached:
                return choice
            if best is None or prediction.weakest > best.prediction.weakest:
                best = choice
    return best
