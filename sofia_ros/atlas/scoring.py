"""How right the model a truth task ends on is: exact, equivalent, extra or missed (docs/atlas.md, "Truths").

A search is right when it ends ``explained`` with the hidden effects added, up to what the output
itself says could stand for them: a member of the same competing set, a rival of a model term, an
equivalent model ("X instead of Y", within delta-BIC 10), or a hidden effect the final comparison
calls unobservable (absorbed by the terms there). A control is right when it ends explained with
nothing added. bench/bench_search_truths.py and the atlas share these rules.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping

__all__ = ['SCORES', 'SUCCESSES', 'confused_pairs', 'equivalent_pairs', 'score_truth', 'stated_competitors',
           'stated_pairs']

#: exact: the hidden effects, no more; equivalent: right up to stated competitors or equivalent models;
#: extra: every hidden effect there (or stood for), but another term too; missed: not explained, a hidden effect
#: neither found nor stood for, or a term of the model taken out.
SCORES = ('exact', 'equivalent', 'extra', 'missed')
SUCCESSES = frozenset({'exact', 'equivalent'})


def equivalent_pairs(equivalents: Iterable[Mapping]) -> set[frozenset]:
    """Pairs {in the model, could stand instead} of the search's 'X instead of Y' equivalents (names joined by
    ' and ')."""
    pairs = set()
    for entry in equivalents:
        text = entry['model'].replace(' (compared in full)', '')
        if ' instead of ' in text:
            others, terms = (part.split(' and ') for part in text.split(' instead of '))
            pairs.update(frozenset((term, other)) for term in terms for other in others if term != other)
    return pairs


def stated_competitors(document: Mapping) -> list[list[str]]:
    """The competing sets a comparison states: each competing set of candidates, and each model term with the
    rivals that could take its place."""
    sets = [list(entry['effects']) for entry in document.get('competing', [])]
    sets += [[entry['term'], *(rival['effect'] for rival in entry['rivals'])]
             for entry in document.get('model_terms', []) if entry['rivals']]
    return sets


def stated_pairs(competing: Iterable[Iterable[str]], equivalents: Iterable[Mapping]) -> set[frozenset]:
    """Every pair of effects stated as standing for each other: two members of one competing set, or an
    equivalent model's swap."""
    pairs = equivalent_pairs(equivalents)
    for members in competing:
        members = list(members)
        pairs.update(frozenset((a, b)) for i, a in enumerate(members) for b in members[i + 1:] if a != b)
    return pairs


def score_truth(hidden: Iterable[str], added: Iterable[str], removed: Iterable[str], status: str,
                stated: set[frozenset], absorbed: Iterable[str] = ()) -> str:
    """The score (SCORES) of a final model: ``added``/``removed`` against the model given, ``status`` its verdict,
    ``stated`` the pairs of stated_pairs, ``absorbed`` the hidden effects the final comparison calls unobservable."""
    hidden, added, absorbed = set(hidden), set(added), set(absorbed)
    if status != 'explained' or set(removed):
        return 'missed'
    if added == hidden:
        return 'exact'
    covered = all(name in added or name in absorbed or any(frozenset((name, term)) in stated for term in added)
                  for name in hidden)
    if not covered:
        return 'missed'
    clean = all(name in hidden or any(frozenset((name, truth)) in stated for truth in hidden) for name in added)
    return 'equivalent' if clean else 'extra'


def confused_pairs(hidden: Iterable[str], added: Iterable[str]) -> list[tuple[str, str]]:
    """(hidden effect not in the final model, a term there the truth lacks): every such pair, sorted."""
    hidden, added = set(hidden), set(added)
    return sorted((name, other) for name in hidden - added for other in added - hidden)
