"""Closing the circle: the achieved separation of a competing set on a bag, by full refits (docs/design.md).

Each member is switched on where it vanishes (on the designed flight: where its fit on the old
bag put it) and fitted in full with the model's terms (compare.fit.fit_model through
compare.run.BagSource, the comparison's own robust fit); the achieved separation is the
difference of the two fits' BIC, compare's BIC of every row at full weight.
"""

from __future__ import annotations

from typing import Mapping, Sequence, TypedDict

from sofia_ros.compare.fit import free_parameters
from sofia_ros.compare.pipeline import switched_on
from sofia_ros.compare.run import BagSource
from sofia_ros.config import EffectConfig

__all__ = ['MemberFit', 'member_fits']


class MemberFit(TypedDict):
    """One member fitted in full on a bag: its BIC, whitened RSS (the prior's rows included) and fitted values."""

    bic: float
    rss: float
    values: dict
    sigma: dict


def member_fits(observations: object, model: EffectConfig, members: Sequence[Sequence[str]], *,
                anchor_spacing_s: float = 30.0, start: Mapping[str, Mapping[str, float]] | None = None) -> dict:
    """Each member fitted in full with the model's fitted terms.

    Args:
        observations: the bag's observations (compare.observations.read_observations).
        model: the model.
        members: each member's effect names.
        anchor_spacing_s: seconds between attitude anchors.
        start: per member name, {label: value} its parameters start from (its fit on a bag of the same telescope:
            the old bag, for the designed flight); by default each starts where it vanishes.

    Returns:
        {member name ('+'-joined): MemberFit}.

    Raises:
        FitError: a fit fails.
    """
    source = BagSource(observations, model, anchor_spacing_s=anchor_spacing_s)
    shared = free_parameters(source.ledger_terms())
    base = source.fit(source.effects, shared, None)
    fits = {}
    for member in members:
        effects, free = dict(base.effects), list(shared)
        for name in member:
            added, _, effects = switched_on(effects, name)
            free += list(added)
        given = (start or {}).get('+'.join(member), {})
        effects = {effect: {**params, **{parameter.name: given[parameter.label] for parameter in free
                                          if parameter.effect == effect in member and parameter.label in given}}
                   for effect, params in effects.items()}
        fit = source.fit(effects, tuple(free), base)
        fits['+'.join(member)] = MemberFit(
            bic=float(fit.bic), rss=float(fit.augmented_residual @ fit.augmented_residual),
            values={p.label: float(v) for p, v in zip(fit.free, fit.values)},
            sigma={p.label: float(s) for p, s in zip(fit.free, fit.sigma)})
    return fits
