"""The libraries of plan elements `sofia design` chooses from, and the choice (docs/design.md).

Each element is one plan element of docs/plans.md (the only maneuvers the calibration node can
fly), or a temperature step and the slews flown after it. The alignment's: Table 3.4's moves at
another elevation, LOS rotations, holds at a LOS angle, a longer hold, and where the truth's
thermal control allows, temperature steps. The star hop's: holds on the plan's stars, a longer
hold, and holds with the star placed across a camera's field. A library is flown once, on the
nominal truth after a short campaign (each temperature step in a flight of its own, at the time and
temperature the designed plan will start it at), to learn each element's geometry and flight time;
an element is then summarized by its profiled information.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass
from typing import Mapping, Sequence

import numpy as np

from sofia_ros.design.separation import Information, expected_delta_bic, noncentrality, sigma_of
from sofia_ros.errors import InvalidArgumentError

__all__ = ['ALIGNMENT_LIBRARY', 'CAMPAIGN_END_PROBE', 'ELEMENT_OVERHEAD_S', 'STAR_HOP_HOLD_S', 'STAR_HOP_OTHER_STARS',
           'STAR_HOP_PLACEMENTS', 'THERMAL_SLEW_ELEVATIONS_DEG', 'THERMAL_SLEW_HOLD_S', 'WAIT_HOLD_S', 'Choice',
           'Element', 'Hypothesis', 'Prediction', 'choose_elements', 'is_thermal', 'predict', 'smallest_flight_s',
           'star_hop_library', 'thermal_library', 'waiting_holds']


@dataclass(frozen=True)
class Element:
    """One element of the library: a short name, its plan-file mapping, and any plan elements flown right after it as
    part of it (a temperature step, then the moves that see the new temperature)."""

    name: str
    document: Mapping
    then: tuple = ()

    @property
    def plan_elements(self) -> list:
        """The plan-file mappings it flies, in order."""
        return [dict(self.document), *(dict(step) for step in self.then)]


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

#: Where the star hop's placed holds put the star: two opposite corners of HIPO and of the FPI, arcsec from the
#: detector's centre along its pixel axes, two thirds of each half field (plans.md refuses the outer 10 %). A rotation
#: of field moves opposite corners in opposite directions, a boresight offset moves them alike, and HIPO's own centre
#: is no longer where the star sits: what tells imager terms from HIPO's fiducial and from each other. The FFI's
#: corners are left out: out there the placement asks the fine drive for more than its +-3 deg once the Earth has
#: walked it along XEL (a flight of the library ended so at 600" from the FFI's centre).
STAR_HOP_PLACEMENTS = (
    ('hipo', (110.0, 100.0)), ('hipo', (-110.0, -100.0)),
    ('fpi', (170.0, 170.0)), ('fpi', (-170.0, -170.0)),
)
#: How many of a plan's other stars the star hop's library holds (a 17-observation plan has six stars; each costs a
#: slew and an acquisition in the library flight, and doubles the subsets the choice tries).
STAR_HOP_OTHER_STARS = 3
#: The star hop's short and long holds (s): its own observations' length, and about one 5.2 min period of the tracker
#: drift (6.3) in a single hold.
STAR_HOP_HOLD_S = (60.0, 320.0)


def star_hop_library(stars: Sequence[str]) -> tuple:
    """The star hop's elements for a plan observing ``stars``: each placement of STAR_HOP_PLACEMENTS on its last star
    (no slew), a hold on it and on the other stars first observed last (more stars, other elevations), and a longer
    hold on the last.

    Args:
        stars: the plan's observed stars in order (catalogue names).

    Returns:
        The Elements.
    """
    home = stars[-1]
    short_s, long_s = STAR_HOP_HOLD_S
    # The long hold last: the Earth walks the fine drive along XEL while a star is held, and the placements need room.
    elements = [Element(f'{home} {short_s:.0f} s at {camera.upper()} ({x:+.0f}", {y:+.0f}")',
                        {'hold': {'star': home, 'duration_s': short_s, 'camera': camera,
                                  'detector_offset_arcsec': [x, y]}})
                for camera, (x, y) in STAR_HOP_PLACEMENTS]
    # Of the other stars, those first observed last (the likeliest still in reach), in the plan's order.
    others = [star for star in dict.fromkeys(stars) if star != home][-STAR_HOP_OTHER_STARS:]
    elements += [Element(f'hold {short_s:.0f} s on {star}', {'hold': {'star': star, 'duration_s': short_s}})
                 for star in (home, *others)]
    elements.append(Element(f'hold {long_s:.0f} s on {home}', {'hold': {'star': home, 'duration_s': long_s}}))
    return tuple(elements)


#: The two ends of a temperature step's slew: a scale factor shows only while the telescope turns, and a slew of tens
#: of degrees turns it far more than Table 3.4's moves. The step is held at one end and the telescope then slews to
#: the other, so that the element flies the same 30 deg slew wherever the telescope was before it: in the library
#: flight (after another element) as in the designed plan (after the plan's last star, 59 deg for the full alignment).
#: Held where the telescope happened to be, with slews to 25 and 55 deg after it, the library's first slew was 18 deg
#: and the designed plan's 35, and the prediction (from the library) fell short of the flight by a factor 2 (issue
#: 28's gyro set, seed 1); with the move to the step's end and a second slew, the element outgrew the budget.
THERMAL_SLEW_ELEVATIONS_DEG = (25.0, 55.0)
#: How long the telescope waits at the slew's end, s: enough for the frames of the position.
THERMAL_SLEW_HOLD_S = 20.0


def thermal_library(min_c: float, max_c: float, time_constant_s: float) -> tuple:
    """The alignment's thermal elements for a truth whose thermal control reaches ``min_c``..``max_c``.

    A step to each end held one time constant at one end of THERMAL_SLEW_ELEVATIONS_DEG (the warm one at the high
    end), then a slew to the other end (a short hold there) while the temperature still follows it: a
    temperature-dependent scale factor against a constant one. And a step to the warm end held two and a half time
    constants, alone: a temperature-driven shift against one that follows time.

    Args:
        min_c: the control's lowest setpoint (deg C).
        max_c: its highest.
        time_constant_s: how slowly the temperature follows the setpoint (s).

    Returns:
        The Elements.
    """
    elements = []
    low_deg, high_deg = THERMAL_SLEW_ELEVATIONS_DEG
    for verb, target, held_deg, slew_deg in (('warm', max_c, high_deg, low_deg), ('cool', min_c, low_deg, high_deg)):
        step = {'target_c': target, 'duration_s': time_constant_s, 'elevation_deg': held_deg}
        slew = {'hold': {'duration_s': THERMAL_SLEW_HOLD_S, 'elevation_deg': slew_deg}}
        elements.append(Element(f'{verb} to {target:.0f} C at {held_deg:.0f} deg for {time_constant_s:.0f} s, '
                                f'then a slew to {slew_deg:.0f} deg', {'temperature': step}, (slew,)))
    held_s = 2.5 * time_constant_s
    elements.append(Element(f'warm to {max_c:.0f} C, held {held_s:.0f} s',
                            {'temperature': {'target_c': max_c, 'duration_s': held_s}}))
    return tuple(elements)


def is_thermal(element: Element) -> bool:
    """Whether ``element`` commands the temperature."""
    return any('temperature' in step for step in element.plan_elements)


#: The longest hold a library flight waits in: the Earth's turn walks the fine drive's LOS about 3 deg in 12 minutes,
#: and a hold driven into its end stop ends the flight there (docs/plans.md); each hold starts back at LOS 0.
WAIT_HOLD_S = 300.0
#: What a hold or temperature element flown at the elevation where the telescope is adds to its duration_s in a flight
#: (the star centred, the frames of the position): 6-9 s, 15 s for a hold of 1 s, in issue 28's library flights; taken
#: at 15, a step's flight starts it about 25 s before the time aimed at (0.007 C of the night's course).
ELEMENT_OVERHEAD_S = 15.0


def waiting_holds(wait_s: float) -> tuple:
    """Holds at LOS 0, each at most WAIT_HOLD_S, that fill about ``wait_s`` of flight (their overhead counted).

    Args:
        wait_s: the flight time to fill (s); none is filled below one element's overhead.

    Returns:
        The Elements (none for a wait too short for one).
    """
    if wait_s <= ELEMENT_OVERHEAD_S + 1.0:
        return ()
    count = int(np.ceil(wait_s / (WAIT_HOLD_S + ELEMENT_OVERHEAD_S)))
    held_s = round(wait_s / count - ELEMENT_OVERHEAD_S, 1)
    return tuple(Element(f'wait {held_s:g} s ({index + 1} of {count})',
                         {'hold': {'duration_s': held_s, 'los_deg': 0.0}}) for index in range(count))


#: A library flight that finds when the short campaign ends, which every library flight of one plan and truth shares:
#: the shortest hold after it.
CAMPAIGN_END_PROBE = Element('to the end of the short campaign', {'hold': {'duration_s': 1.0, 'los_deg': 0.0}})


@dataclass(frozen=True)
class Hypothesis:
    """One member of the competing set: its name, fitted labels and the size a prediction assumes (its fit on the bag,
    or a catalogue size where the bag does not measure it: design.run.stated_sizes)."""

    name: str
    labels: tuple
    values: np.ndarray


@dataclass(frozen=True)
class Prediction:
    """Expected delta-BIC for each direction ('A true' -> 'B' loses by), what of the true member's signature the rival
    leaves (lambda / s^2, the non-centrality in noise units), and the members' sigmas."""

    separation: dict
    signature_left: dict
    sigma: dict
    rows: int

    @property
    def weakest(self) -> float:
        """The smaller of the two directions: the separation whichever member is true."""
        return min(self.separation.values())

    def weakest_of(self, directions: Sequence[str]) -> float:
        """The smallest separation among ``directions`` (the true members' names)."""
        return min(self.separation[name] for name in directions)


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
    separation, left, sigma = {}, {}, {}
    for true, rival in ((first, second), (second, first)):
        value = noncentrality(information, true.labels, true.values, rival.labels, shared)
        separation[true.name] = expected_delta_bic(value, len(true.labels), len(rival.labels), information.rows,
                                                   variance)
        left[true.name] = value / variance
        fitted = [*shared, *true.labels]
        sigma[true.name] = dict(zip(fitted, sigma_of(information, fitted, variance).tolist()))
    return Prediction(separation, left, sigma, information.rows)


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
                    target: float, budget_s: float, directions: Sequence[str] | None = None) -> Choice:
    """The fewest elements (then the shortest flight) whose expected delta-BIC reaches ``target`` in ``directions``.

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
        target: the delta-BIC to reach in each of ``directions``.
        budget_s: the largest flight time allowed.
        directions: the true members' names whose separation counts (default both; a direction the rival reproduces
            whatever is flown is left out by the caller).

    Returns:
        The Choice.

    Raises:
        InvalidArgumentError: the budget is below the shortest element.
    """
    if budget_s < smallest_flight_s(flight_s):
        raise InvalidArgumentError(f'a budget of {budget_s:.0f} s is below the shortest element '
                                   f'({smallest_flight_s(flight_s):.0f} s); raise --budget-s')
    directions = (first.name, second.name) if directions is None else tuple(directions)
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
            weakest = prediction.weakest_of(directions)
            choice = Choice(subset, seconds, prediction, weakest >= target)
            if choice.reached:
                return choice
            if best is None or weakest > best.prediction.weakest_of(directions):
                best = choice
    return best
