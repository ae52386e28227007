"""`sofia design`'s prediction: which plan elements separate a competing set, and by how much (docs/design.md).

1. The old bag: the model fitted, both members linearized at the fit (design.geometry); each
   member's size is its linearized fit on the bag (what the comparison would fit), except a
   scaling parameter the bag does not measure, which is taken at its catalogue size and said so
   (stated_sizes); the residual variance is what the better member's full refit leaves.
2. The library flights: the same columns over each element's window of the bags that flew the
   library on the nominal truth (each temperature step in a flight of its own, started at the
   bag's end time and last temperature, as the designed plan starts it); each element's profiled
   information, flight time and start.
3. Each element's expected separation per minute, each set's prediction, the choice
   (design.elements.choose_elements). A direction in which the rival reproduces the true member
   even with every element flown (REPRODUCED_BELOW) is one no plan can separate: it is named,
   and the choice is made for the other.
"""

from __future__ import annotations

from typing import Sequence, TypedDict

import numpy as np
import yaml

from sofia_ros.analysis.ranking import whitened_bic
from sofia_ros.compare.fit import FreeParameter, free_parameters
from sofia_ros.config import EffectConfig
from sofia_ros.design.check import member_fits
from sofia_ros.design.elements import Choice, Element, Hypothesis, Prediction, choose_elements, predict
from sofia_ros.design.geometry import BagColumns, ModelOnBag, bag_columns, element_windows, member_labels
from sofia_ros.design.separation import Information, fitted_values, rss_drop, sigma_of
from sofia_ros.effects import get_effect
from sofia_ros.errors import BagError, ConfigError

__all__ = ['MEASURED_AT_SIGMA', 'REPRODUCED_BELOW', 'DesignDocument', 'ElementEntry', 'StatedSize', 'check_members',
           'design_plan', 'flown_elements', 'member_name', 'stated_sizes']

#: A true member's signature that the rival leaves less of than this (lambda / s^2, in units of the noise variance)
#: is one it reproduces: the BIC cannot see it, only the members' parameter counts.
REPRODUCED_BELOW = 1.0


class ElementEntry(TypedDict):
    """One library element in the JSON: what it is (its plan elements), how long it flies, what it adds."""

    name: str
    element: list
    flight_s: float
    start_s: float
    separation: dict
    separation_per_minute: dict
    sigma_ratio: dict


class StatedSize(TypedDict):
    """A parameter the bag does not measure, taken at its catalogue size for the prediction (docs/design.md)."""

    value: float
    unit: str
    bag_value: float
    bag_sigma: float


class DesignDocument(TypedDict):
    """`sofia design --json` (docs/design.md)."""

    bag: str
    model: str | None
    anchor_s: float
    members: list
    shared: list
    flight_s: float
    elements_start_s: float
    budget_s: float
    target_delta_bic: float
    sizes: dict
    assumed_sizes: dict
    observed_delta_bic: dict
    before: dict
    elements: list
    status: str
    chosen: list
    chosen_flight_s: float
    flight_share: float
    predicted: dict
    sigma_before: dict
    sigma_after: dict
    skipped: list
    whole_library: dict
    reproduced: list


def member_name(member: Sequence[str]) -> str:
    """A member as the command line spells it: its effects joined by '+'."""
    return '+'.join(member)


def _observed_delta_bic(columns: BagColumns, information: Information, labels: Sequence[str]) -> float:
    """compare's delta-BIC of a member on the bag, linearized (analysis.ranking.whitened_bic)."""
    after = columns.rss - rss_drop(information, [*columns.shared_labels, *labels])
    return whitened_bic(columns.rss, columns.rows, 0) - whitened_bic(max(after, 0.0), columns.rows, len(labels))


def _residual_variance(observations: object, model: EffectConfig, members: Sequence[Sequence[str]], rows: int,
                       anchor_spacing_s: float) -> float:
    """s^2: the whitened RSS per row the better member's full refit leaves on the bag (compare's own fit).

    Not the linearized step from the model's fit: where a member's signature is large, that step leaves what the
    linearization misses as if it were noise (43770 against the refit's 33250 on issue 28's gyro set, seed 2; 16800
    against 4820 on the minimal alignment's HIPO set), and every separation divided by it came out that much too small.
    """
    fits = member_fits(observations, model, members, anchor_spacing_s=anchor_spacing_s)
    # Below the floor compare's BIC counts the chi-square (analysis.ranking.whitened_bic): the variance is the floor's.
    return max(min(fit['rss'] for fit in fits.values()) / rows, 1.0)


#: An estimate at least this many of its sigmas from zero is one the bag measures (stated_sizes).
MEASURED_AT_SIGMA = 3.0


def stated_sizes(parameters: Sequence[FreeParameter], values: np.ndarray,
                 sigma: np.ndarray) -> tuple[np.ndarray, dict]:
    """The size a prediction assumes for a member: its fit on the bag, except where the bag does not measure a scaling
    parameter (its estimate within MEASURED_AT_SIGMA sigmas of zero, and that bound not below its catalogue size),
    which is taken at the catalogue's size.

    The separation grows with the square of what tells the members apart, and that is often the one number the bag
    could not measure (gyro_axis_swap's temperature coefficient on a night without a temperature step: 8.4 +- 55 ppm/C,
    the catalogue's 20): its estimate is noise, and a prediction scaled by it was 5.7 times too small. Noise of 1-2
    sigmas counts as no measurement too: a HIPO fiducial centre the imagers' fitted offsets leave free read
    -764 +- 400 px against a true -8.8, and a prediction scaled by it was that much too large. A parameter the bag
    bounds below its catalogue size (a scale factor of 2 +- 21 ppm against 400) keeps its estimate, and so does a
    shaping one (a period: no size) or one whose catalogue size is zero (a plug-in's: no size stated).

    Args:
        parameters: the member's fitted parameters (compare.fit.free_parameters), in the order of ``values``.
        values: their linearized fit on the bag.
        sigma: their 1-sigma on the bag, fitted with the model's terms.

    Returns:
        (the sizes to predict with, {label: StatedSize} of those taken at the catalogue's size).
    """
    sizes, assumed = np.array(values, dtype=float), {}
    for index, parameter in enumerate(parameters):
        spec = get_effect(parameter.effect).parameter(parameter.name)
        catalogue = float(spec.default)
        bound = MEASURED_AT_SIGMA * sigma[index]
        undetermined = bound > abs(values[index]) and bound >= abs(catalogue)
        if spec.shape or catalogue == 0.0 or not undetermined:
            continue
        sizes[index] = catalogue
        assumed[parameter.label] = StatedSize(value=catalogue, unit=parameter.unit,
                                              bag_value=float(values[index]), bag_sigma=float(sigma[index]))
    return sizes, assumed


def _hypotheses(columns: BagColumns, information: Information, members: Sequence[Sequence[str]]) -> list:
    """Each member as the bag fits it (its linearized fit with the model's terms)."""
    shared = list(columns.shared_labels)
    hypotheses = []
    for member in members:
        labels = member_labels(member)
        values = fitted_values(information, [*shared, *labels])[len(shared):]
        hypotheses.append(Hypothesis(member_name(member), labels, values))
    return hypotheses


def _assumed_hypotheses(information: Information, shared: Sequence[str], members: Sequence[Sequence[str]],
                        fitted: Sequence[Hypothesis], variance: float) -> tuple[list, dict]:
    """The members at the sizes the prediction assumes (stated_sizes), and {member: {label: StatedSize}}."""
    hypotheses, assumed = [], {}
    for member, hypothesis in zip(members, fitted):
        sigma = sigma_of(information, [*shared, *hypothesis.labels], variance)[len(shared):]
        sizes, assumed[hypothesis.name] = stated_sizes(free_parameters(member), hypothesis.values, sigma)
        hypotheses.append(Hypothesis(hypothesis.name, hypothesis.labels, sizes))
    return hypotheses, assumed


def flown_elements(calibration_text: str | None, library_elements: Sequence[Element]) -> tuple[list, list]:
    """The library elements a flight flew with their sim-time windows, from its calibration result; and the names of
    those it skipped (no star in reach).

    Args:
        calibration_text: the flight's calibration result (calibration.yaml's text).
        library_elements: the elements its plan listed, in order (an element of several plan elements takes as many
            consecutive indices).

    Returns:
        ([(Element, start_s, end_s)], [skipped names]): an element's window runs from its first plan element's start to
        its last one's end; an element any of whose plan elements was not flown is skipped.

    Raises:
        BagError: the flight has no calibration result.
    """
    if not calibration_text:
        raise BagError('the library flight has no calibration result; delete it so that it is flown again')
    flown = {index: (start, end) for index, _, start, end in element_windows(yaml.safe_load(calibration_text))}
    windows, skipped, first = [], [], 1
    for element in library_elements:
        indices = range(first, first + len(element.plan_elements))
        first = indices.stop
        if all(index in flown for index in indices):
            windows.append((element, flown[indices[0]][0], flown[indices[-1]][1]))
        else:
            skipped.append(element.name)
    return windows, skipped


def _element_information(library: BagColumns, windows: Sequence[tuple]) -> list:
    """(Element, Information without gradient, flight s, start s) of each flown element: what its geometry adds."""
    out = []
    for element, start, end in windows:
        information = library.information(start, end)
        out.append((element, Information(information.labels, information.gram, np.zeros_like(information.gradient),
                                         information.rows), end - start, start))
    return out


def _sigma_ratio(before: Prediction, after: Prediction) -> dict:
    return {name: {label: (after.sigma[name][label] / sigma if np.isfinite(sigma) and sigma > 0 else None)
                   for label, sigma in before.sigma[name].items()} for name in before.sigma}


def check_members(model: EffectConfig, members: Sequence[Sequence[str]]) -> None:
    """Refuse a member the model already has: a competing member is an effect the model lacks.

    Args:
        model: the model.
        members: each member's effect names.

    Raises:
        ConfigError: naming the effect and the model.
    """
    for member in members:
        for name in member:
            if name in model.effects:
                raise ConfigError(f'{name} is already in the model {model.source}; a competing member is an effect '
                                  'the model lacks (remove it from the model, or name another)')


def design_plan(observations: object, library: Sequence[tuple], skipped: Sequence[str], model: EffectConfig,
                members: Sequence[Sequence[str]], *, flight_s: float, budget_s: float, target: float,
                anchor_spacing_s: float = 30.0, on_bag: ModelOnBag | None = None) -> DesignDocument:
    """The prediction and the choice for one competing set of two members.

    Args:
        observations: the old bag's observations.
        library: per library flight, (its observations, the (Element, start_s, end_s) of each library element it flew
            (flown_elements)); each temperature step is flown in a flight of its own.
        skipped: the names of the library elements the flights could not fly.
        model: the model compared (its fitted terms are shared by both members).
        members: the two members, each a list of effect names.
        flight_s: the old bag's flight time (s).
        budget_s: the largest addition (s).
        target: the expected delta-BIC to reach in both directions (in the one left, where the rival reproduces the
            other member whatever is flown).
        anchor_spacing_s: seconds between attitude anchors.
        on_bag: the model already fitted to the old bag (design.geometry.fit_model_on_bag), or None: fitted here.

    Returns:
        The DesignDocument (``status``: already_separated; inseparable, where a direction no element can separate is
        left and the others are separated already; designed or not_reached).

    Raises:
        ConfigError: a member already in the model.
        InvalidArgumentError: a budget below the shortest element.
        FitError: the model's fit fails.
    """
    check_members(model, members)
    old = bag_columns(observations, model, members, anchor_spacing_s=anchor_spacing_s, on_bag=on_bag)
    base = old.information()
    fitted = _hypotheses(old, base, members)
    shared = list(old.shared_labels)
    variance = _residual_variance(observations, model, members, old.rows, anchor_spacing_s)
    (first, second), assumed = _assumed_hypotheses(base, shared, members, fitted, variance)
    before = predict(base, shared, first, second, variance)
    elements = []
    for flight, windows in library:
        if windows:  # a flight whose elements were all skipped measures nothing: no fit of it
            columns = bag_columns(flight, model, members, anchor_spacing_s=anchor_spacing_s)
            elements += _element_information(columns, windows)
    if not elements:
        raise BagError('the library flight flew none of its elements (no star in reach); see its summary.json')
    entries = []
    for element, information, seconds, start in elements:
        alone = predict(base + information, shared, first, second, variance)
        per_minute = {name: 60.0 * (alone.separation[name] - before.separation[name]) / seconds
                      for name in alone.separation}
        entries.append(ElementEntry(name=element.name, element=element.plan_elements, flight_s=round(seconds, 1),
                                    start_s=round(start, 1), separation=alone.separation,
                                    separation_per_minute=per_minute, sigma_ratio=_sigma_ratio(before, alone)))
    whole = base
    for _, information, _, _ in elements:
        whole = whole + information
    with_all = predict(whole, shared, first, second, variance)
    # A direction the rival reproduces even with every element flown is one no plan of these elements can separate:
    # the choice is made for the others.
    reproduced = [name for name, left in with_all.signature_left.items() if left < REPRODUCED_BELOW]
    separable = [name for name in before.separation if name not in reproduced]
    document = DesignDocument(
        bag=str(observations.bag_path), model=model.source, anchor_s=float(anchor_spacing_s),
        members=[member_name(m) for m in members],
        shared=shared, flight_s=round(flight_s, 1),
        elements_start_s=round(float(observations.centroids.stamp_s.max()), 1), budget_s=round(budget_s, 1),
        target_delta_bic=target,
        sizes={member.name: dict(zip(member.labels, member.values.tolist())) for member in fitted},
        assumed_sizes=assumed,
        observed_delta_bic={member_name(m): _observed_delta_bic(old, base, member_labels(m)) for m in members},
        before=before.separation, elements=entries, status='already_separated', chosen=[], chosen_flight_s=0.0,
        flight_share=0.0, predicted=before.separation, sigma_before=before.sigma, sigma_after=before.sigma,
        skipped=list(skipped), reproduced=reproduced,
        whole_library={'flight_s': round(sum(seconds for _, _, seconds, _ in elements), 1),
                       'separation': with_all.separation, 'signature_left': with_all.signature_left})
    if not separable or before.weakest_of(separable) >= target:
        document['status'] = 'inseparable' if reproduced else 'already_separated'
        return document
    choice: Choice = choose_elements(base, [information for _, information, _, _ in elements],
                                     [seconds for _, _, seconds, _ in elements], shared, first, second, variance,
                                     target=target, budget_s=budget_s, directions=separable)
    document.update(status='designed' if choice.reached else 'not_reached',
                    chosen=[{'name': elements[index][0].name, 'element': elements[index][0].plan_elements}
                            for index in choice.indices],
                    chosen_flight_s=round(choice.flight_s, 1), flight_share=choice.flight_s / flight_s,
                    predicted=choice.prediction.separation, sigma_after=choice.prediction.sigma)
    return document
