"""Competing explanations, for bags and measurement sets alike (docs/compare.md, "Competing explanations").

The ranking (analysis.ranking) says which candidates explain the same residual about equally
well; this module decides which of them are refitted in full, which one the verdict takes
(physics before an empirical shape that mimics it), and writes each competing set as the JSON
and the printed block show it: its members, their delta-BIC, how much they share, what the
comparison says with each of them, and on which observables they differ.
"""

from __future__ import annotations

from typing import Any, Iterable, Mapping, TypedDict

from sofia_ros.analysis.ranking import CompetingSet, RankedCandidate
from sofia_ros.compare.fit import free_parameters
from sofia_ros.effects.empirical import is_empirical

__all__ = ['AfterMember', 'CompetingEntry', 'REFINED_CANDIDATES', 'REFINED_PHYSICAL', 'SEPARATING_RATIO_GAP',
           'competing_document', 'competing_lines', 'competing_set_of', 'contenders', 'preferred_best', 'refit_order']

#: The strongest candidates of the linearized ranking are refitted in full (nonlinear, robust)...
REFINED_CANDIDATES = 3
#: ...and so are this many more physical ones: an effect linearized where it vanishes (a clock offset at 0 s)
#: can score far below what its refit reaches, behind empirical shapes that take the first slots (issue 25).
REFINED_PHYSICAL = 2
#: An observable separates two members when the RMS / floor left with one differs from the other's by this much.
SEPARATING_RATIO_GAP = 0.1


class AfterMember(TypedDict):
    """The comparison refitted with one member: its status and the observables still unexplained."""

    status: str
    unexplained: list[str]
    ratios: dict[str, float]


class CompetingEntry(TypedDict):
    """One competing set of the JSON (docs/compare.md)."""

    effects: list[str]
    delta_bic: dict[str, float]
    shared_fraction: float
    margin_delta_bic: float
    verdict_with_each: dict[str, str | None]
    separable_by: list[str]


def refit_order(ranked: Iterable[RankedCandidate]) -> list[RankedCandidate]:
    """The significant candidates refitted in full: the REFINED_CANDIDATES strongest, then REFINED_PHYSICAL more
    physical ones (catalogue or plug-in effects, not empirical shapes).

    Args:
        ranked: the linearized ranking, strongest first.

    Returns:
        The candidates to refit, in ranking order.
    """
    significant = [candidate for candidate in ranked if candidate.significant]
    chosen = significant[:REFINED_CANDIDATES]
    physical = [c for c in significant[REFINED_CANDIDATES:] if not is_empirical(c.name)]
    return chosen + physical[:REFINED_PHYSICAL]


def competing_set_of(name: str | None, competing: Iterable[CompetingSet]) -> CompetingSet | None:
    """The competing set ``name`` belongs to, or None.

    Args:
        name: a candidate's name, or None.
        competing: the competing sets of the ranking.

    Returns:
        The first set with ``name`` among its effects, or None.
    """
    return next((entry for entry in competing if name in entry.effects), None)


def contenders(refitted: Iterable[str], scores: Mapping[str, float], competing: Iterable[CompetingSet]) -> list[str]:
    """The refitted candidates the verdict chooses among: the best delta-BIC and the refitted members of its
    competing set (the comparison is judged again with each of them). Empty when nothing was refitted.

    Args:
        refitted: the names of the candidates refitted in full.
        scores: each refitted candidate's delta-BIC.
        competing: the competing sets of the ranking.

    Returns:
        The contenders' names.
    """
    refitted = list(refitted)
    if not refitted:
        return []
    best = max(refitted, key=lambda name: scores[name])
    rivals = competing_set_of(best, competing)
    return [best] if rivals is None else [name for name in rivals.effects if name in refitted]


def preferred_best(names: Iterable[str], scores: Mapping[str, float], after: Mapping[str, AfterMember],
                   competing: Iterable[CompetingSet] = ()) -> str | None:
    """The contender the verdict takes: one that explains every observable before one that does not, physics
    before an empirical shape, then the best delta-BIC; but within its competing set, among members of the same
    standing, the one with the fewest free parameters (then the best delta-BIC). None when there is none.

    Members of a competing set differ by less than the competing margin, which is there because a model that
    still lacks effects leaves a residual whose BIC differences are decided by what else is missing: the data do
    not choose, and the explanation with fewer free numbers is the one a later round can least overfit (on the
    Waco 2004 alignment the HIPO fiducial error, 3 numbers, against a boresight offset of 6).

    Args:
        names: the contenders' names.
        scores: each contender's delta-BIC.
        after: what the comparison says with each contender refitted (its status).
        competing: the competing sets of the ranking.

    Returns:
        The preferred contender's name, or None when ``names`` is empty.
    """
    names = list(names)

    def standing(name):
        return after.get(name, {}).get('status') != 'explained', is_empirical(name)

    top = min(names, key=lambda name: (*standing(name), -scores[name]), default=None)
    rivals = competing_set_of(top, competing) if top is not None else None
    if rivals is None:
        return top
    peers = [name for name in names if name in rivals.effects and standing(name) == standing(top)]
    return min(peers, key=lambda name: (len(free_parameters([name])), -scores[name]))


def _separating_observables(after: Mapping[str, AfterMember]) -> list:
    """Observables on which the members leave different residuals, the largest gap in RMS / floor first."""
    if len(after) < 2:
        return []
    names = set.intersection(*(set(member['ratios']) for member in after.values()))
    gaps = {}
    for observable in names:
        ratios = [member['ratios'][observable] for member in after.values()]
        gap = max(ratios) - min(ratios)
        if gap >= SEPARATING_RATIO_GAP * max(min(ratios), 1.0):
            gaps[observable] = gap
    return sorted(gaps, key=lambda observable: -gaps[observable])[:3]


def competing_document(competing: Iterable[CompetingSet],
                       after: Mapping[str, AfterMember]) -> list[CompetingEntry]:
    """The JSON's ``competing`` list: each set with what the comparison says with each member (None: not refitted).

    Args:
        competing: the competing sets of the ranking.
        after: what the comparison says with each refitted member.

    Returns:
        One entry per set.
    """
    document = []
    for entry in competing:
        members = {name: after[name] for name in entry.effects if name in after}
        document.append(CompetingEntry(
            effects=list(entry.effects), delta_bic=dict(entry.delta_bic),
            shared_fraction=round(entry.shared_fraction, 4), margin_delta_bic=round(entry.margin, 1),
            verdict_with_each={name: after[name]['status'] if name in after else None for name in entry.effects},
            separable_by=_separating_observables(members)))
    return document


def competing_lines(document: Mapping[str, Any], source: str) -> list[str]:
    """The printed block of competing explanations, degenerate pairs and the model's questioned terms (one
    renderer for bags and measurement sets; ``source`` is 'campaign' or 'set').

    Args:
        document: the comparison's JSON document (its degenerate, competing, model_terms and equivalent_models).
        source: what was compared, 'campaign' or 'set', as the lines name it.

    Returns:
        The printed lines, indented, without newlines.
    """
    lines = []
    for first, second in document['degenerate']:
        lines.append(f'  degenerate: {first} and {second} explain the same residual; this {source} cannot tell them '
                     'apart')
    for entry in document.get('competing', []):
        scores = ', '.join(f'{name} {value:.0f}' for name, value in entry['delta_bic'].items())
        judged = [f'{name} {status}' for name, status in entry['verdict_with_each'].items() if status]
        where = f'; they differ most on {", ".join(entry["separable_by"])}' if entry['separable_by'] else ''
        lines.append(f'  competing: {" or ".join(entry["effects"])} (delta-BIC {scores}; '
                     f'{100 * entry["shared_fraction"]:.0f} % shared'
                     + (f'; with each: {", ".join(judged)}' if judged else '') + f'{where})')
    for entry in document.get('model_terms', []):
        if not entry['pays']:
            lines.append(f'  questioned: {entry["term"]} no longer pays for itself (delta-BIC {entry["delta_bic"]:.0f})')
        for rival in entry['rivals'][:2]:
            lines.append(f'  questioned: {rival["effect"]} could take the place of {entry["term"]} (delta-BIC '
                         f'{rival["delta_bic"]:.0f} against {entry["delta_bic"]:.0f}, '
                         f'{100 * rival["shared_fraction"]:.0f} % shared)')
    for entry in document.get('equivalent_models', [])[:3]:
        lines.append(f'  equivalent: {entry["model"]} (delta-BIC {entry["delta_bic"]:+.1f})')
    return lines
