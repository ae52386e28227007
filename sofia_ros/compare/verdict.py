"""The verdict of a comparison: explained only when every camera axis and every gyro axis is (docs/compare.md).

- ``explained``: every observable's RMS is within RATIO_LIMIT of its floor, none holds structure
  (a trend or period at DETECTION_SIGMA, family-wise), and no fitted term changes between
  halves of the data. Its next step may still add a physical effect whose full refit lowers the BIC
  by EXPLAINED_ADDITION_DELTA_BIC, or remove or replace a term that no longer pays for itself.
- ``missing_effect``: not explained, and a catalogue or plug-in effect lowers the BIC
  significantly; the text says whether the comparison refitted with it is explained, or what
  is still left (a term that absorbs physics must not close the loop).
- ``unexplained``: not explained, and no physical effect helps, or only an empirical term
  does: the text names the shape (observable, variable or period) and how to turn it into
  physics (`sofia effects new`), or to keep the empirical term meanwhile (`sofia model add`).
- ``undetermined``: every observable is explained, but by a fit with as many fitted parameters
  as the data have measurements: they fit exactly whatever is wrong, so nothing is tested, and the
  parameters without a finite sigma are not determined either (a calibration needs more data).
"""

from __future__ import annotations

from collections.abc import Callable, Collection, Iterable, Mapping, Sequence
from typing import Any

from sofia_ros.analysis.ranking import CompetingSet
from sofia_ros.compare.competing import AfterMember, competing_set_of
from sofia_ros.compare.diagnostics import DETECTION_SIGMA, Diagnostics, GYRO_AXES, NAMING_PREFERENCE, RATIO_LIMIT, distinct_findings
from sofia_ros.compare.records import NextStep, Verdict
from sofia_ros.effects.empirical import (CAMERA_OBSERVABLES, DETECTOR_FIELD, GYRO_TERM_VARIABLES, VARIABLES, empirical_name,
                                         empirical_parts, is_empirical)

__all__ = ['after_member', 'beyond_bag_floor', 'clipped_headline', 'empirical_candidate_names', 'headline', 'judge',
           'model_command', 'next_step', 'BAG_OBSERVABLE_KEYS', 'EXPLAINED_ADDITION_DELTA_BIC', 'HEADLINE_CHARACTERS',
           'MAX_EMPIRICAL_CANDIDATES']

#: At most this many empirical terms are tried, the strongest findings first.
MAX_EMPIRICAL_CANDIDATES = 8


def _expressible(finding, gyro):
    """The variable an empirical term can use for a trend finding (itself or an equivalent one), or None."""
    allowed = GYRO_TERM_VARIABLES if gyro else (*VARIABLES, DETECTOR_FIELD)
    group = sorted((finding['variable'], *finding.get('equivalent_variables', ())),
                   key=lambda v: NAMING_PREFERENCE.index(v) if v in NAMING_PREFERENCE else len(NAMING_PREFERENCE))
    return next((variable for variable in group if variable in allowed), None)


def _implicated_observables(consistency, cameras):
    """Observables whose fitted term changes between halves: a gyro term's axis, a camera term's two axes, an
    empirical term's own observable."""
    implicated = set()
    for entry in consistency:
        # A label is effect.parameter; an empirical effect's name holds dots of its own (poly3@23.01..59.05).
        effect, _, parameter = entry['param'].rpartition('.')
        if is_empirical(effect):
            implicated.add(empirical_parts(effect)[0])
            continue
        # Parameters name their axis or camera first (gyro_bias.el_deg_per_h, imager_boresight_offset.ffi_el_arcsec).
        prefix = parameter.split('_', 1)[0]
        if prefix in GYRO_AXES:
            implicated.add(f'gyro.{prefix}')
        elif prefix in cameras:
            implicated.update((f'{prefix}.x', f'{prefix}.y'))
    return implicated


def empirical_candidate_names(diagnostics: Diagnostics, cameras: Collection[str],
                              consistency: Sequence[Mapping[str, Any]] = ()) -> list[str]:
    """Empirical terms for the strongest shapes the diagnostics found: one per observable and kind of finding
    (a period, a trend of one variable, a field of the detector position).

    A shape is structure from DETECTION_SIGMA on; on an observable already known to be wrong (its
    RMS is beyond its floor, or a fitted term of its axis changes between halves of the data) a
    listed finding (from REPORT_SIGMA) is the best hint of its shape, and is tried too: the
    ranking's delta-BIC then decides whether it explains anything.

    Args:
        diagnostics: the residual diagnostics of the model's fit.
        cameras: the cameras of the bag.
        consistency: the fitted terms that change between halves of the data (compare.diagnostics.split_consistency).

    Returns:
        The empirical terms' names, at most MAX_EMPIRICAL_CANDIDATES, the strongest findings first.
    """
    implicated = _implicated_observables(consistency, cameras)
    names, seen = [], set()
    for finding in distinct_findings([*diagnostics.trends, *diagnostics.periods]):
        observable = finding['observable']
        entry = diagnostics.observables.get(observable, {})
        if (finding['significance_sigma'] < DETECTION_SIGMA and entry.get('explained', True)
                and observable not in implicated):
            continue
        gyro = observable.startswith('gyro.')
        if not gyro and (observable not in CAMERA_OBSERVABLES or observable.split('.')[0] not in cameras):
            continue
        if 'period_s' in finding:
            key, name = (observable, 'period'), empirical_name(observable, 'time', finding['period_s'])
        else:
            variable = _expressible(finding, gyro)
            if variable is None:
                continue
            # A field of the detector position is tried beside the strongest one-variable trend: where
            # it is the shape, a trend along x or y alone is what is left of it after averaging.
            kind = 'field' if variable == DETECTOR_FIELD else 'trend'
            key, name = (observable, kind), empirical_name(observable, variable,
                                                           range_=finding['ranges'].get(variable))
        if key not in seen:
            seen.add(key)
            names.append(name)
        if len(names) >= MAX_EMPIRICAL_CANDIDATES:
            break
    return names


#: The verdict's text names this many unexplained observables and structures per observable; the JSON has all.
_NAMED = 3
#: An explained comparison still adds a physical effect whose full refit lowers the BIC by this much ("very strong"
#: evidence, Kass & Raftery 1995). The RMS and structure tests are omnibus; an effect's own columns are a targeted
#: test and can find what they call noise: a swapped gyro calibration at its default beside a field rotation and a
#: clock offset at 3x theirs refitted at delta-BIC 56 with every observable explained (bench_search_truths --sizes).
#: In the multi-effect atlas's 80 final comparisons (60 truths, 20 controls), the largest candidate was 7.6. Also
#: where every observable is below its floor: the BIC is the floor-bounded one (analysis.ranking.whitened_bic), which
#: a term fitting noise below the floor cannot raise without bound (the 2004 short moves, 9 distances at 0.24 of their
#: floor, did before it), while an alignment bag's floor, from second differences of the locked frames, sits above its
#: centroid noise (0.37" against 0.30", the tracker's feedback moving the star between frames): a hidden 400 ppm gyro
#: scale factor refitted at delta-BIC 121 and 186 with every ratio below 1 ended "explained: nothing to do".
EXPLAINED_ADDITION_DELTA_BIC = 10.0
#: The keys of a bag observable's judgement the verdict keeps (compare.diagnostics holds more).
BAG_OBSERVABLE_KEYS = ('rms_arcsec', 'floor_arcsec', 'ratio', 'excess_sigma', 'explained', 'structure', 'kind')


def beyond_bag_floor(entry: Mapping[str, Any]) -> bool:
    """A bag's rule for the RMS of an observable (compare.diagnostics): beyond RATIO_LIMIT of its floor with an
    excess of DETECTION_SIGMA, family-wise.

    Args:
        entry: the observable's judgement (its ratio and excess_sigma).

    Returns:
        Whether its RMS alone fails.
    """
    return entry['ratio'] > RATIO_LIMIT and entry['excess_sigma'] >= DETECTION_SIGMA


def _rms_text(entry):
    """An observable's RMS in its unit: arcsec, or arcsec/s for a set's rate observable."""
    if 'rms_arcsec' in entry:
        return f'{entry["rms_arcsec"]:.3f}"'
    return f'{entry["rms_arcsec_per_s"]:.4f}"/s'


def _observable_problem(name, entry, beyond_floor):
    reasons = []
    if beyond_floor(entry):
        reasons.append(f'RMS {_rms_text(entry)} = {entry["ratio"]:.2f}x its floor')
    if entry['structure']:
        more = len(entry['structure']) - 2
        reasons.append('follows ' + ', '.join(entry['structure'][:2]) + (f' (+{more} more)' if more > 0 else ''))
    return f'{name} ' + ' and '.join(reasons)


def _strength(diagnostics, name):
    """How badly an observable fails: its strongest finding's significance, else its RMS excess."""
    findings = diagnostics.structured(name)
    return max((f['significance_sigma'] for f in findings), default=0.0), diagnostics.observables[name]['ratio']


def _problems(diagnostics, consistency, beyond_floor):
    """At most _NAMED problems in plain words, the worst first: the unexplained observables by strength, then the
    terms that change between halves; the rest counted (the JSON and the report list them all)."""
    failing = sorted(diagnostics.unexplained(), key=lambda name: _strength(diagnostics, name), reverse=True)
    clauses = [_observable_problem(name, diagnostics.observables[name], beyond_floor) for name in failing[:_NAMED]]
    for entry in consistency[:_NAMED - len(clauses)]:
        split = entry['split']
        clauses.append(f'{entry["param"]} changes with {split} ({entry["halves"][0]} {entry["values"][0]:.4g} +- '
                       f'{entry["sigmas"][0]:.2g}, {entry["halves"][1]} {entry["values"][1]:.4g} +- '
                       f'{entry["sigmas"][1]:.2g}; {entry["significance_sigma"]:.0f} sigma)')
    left = len(failing) + len(consistency) - len(clauses)
    if left:
        clauses.append(f'{left} more problem{"s" if left > 1 else ""}')
    return clauses


def _plugin_kind(candidate):
    return 'gyro' if candidate['observable'].startswith('gyro.') else 'camera'


def after_member(diagnostics: Diagnostics, consistency: Sequence[Mapping[str, Any]]) -> AfterMember:
    """What the comparison says with a candidate refitted in: explained or not, what is left, RMS / floor per observable.

    Args:
        diagnostics: the residual diagnostics of the refit.
        consistency: the refit's terms that change between halves of the data.

    Returns:
        Its status ('explained' or 'not explained'), the unexplained observables and each observable's RMS / floor.
    """
    unexplained = sorted(set(diagnostics.unexplained())
                         | (_implicated_observables(consistency, {name.split('.')[0] for name in diagnostics.observables})
                            & diagnostics.observables.keys()))
    return {'status': 'explained' if not unexplained and not consistency else 'not explained',
            'unexplained': unexplained,
            'ratios': {name: float(entry['ratio']) for name, entry in diagnostics.observables.items()}}


def _rivals_clause(best_name, rivals, members, gain):
    """What a competing set means for the choice: decided by what each member leaves, or not decided."""
    scores = ', '.join(f'{name} {rivals.delta_bic[name]:.0f}' for name in rivals.effects)
    shared = f'delta-BIC {scores}; {100 * rivals.shared_fraction:.0f} % of the smaller drop shared'
    others = [name for name in rivals.effects if name != best_name and name in members]
    decided = (members[best_name]['status'] == 'explained'
               and all(members[name]['status'] != 'explained' for name in others))
    if others and decided:
        left = sorted({observable for name in others for observable in members[name]['unexplained']})
        return (f'missing effect {best_name} ({gain}); {" and ".join(others)} fit the same residual ({shared}) '
                f'but leave {", ".join(left[:_NAMED])} unexplained')
    return (f'{" or ".join(rivals.effects)}: this data cannot tell them apart ({shared}), so it cannot choose; '
            f'taken first: {best_name} ({gain})')


def model_command(action: str, model_source: str, *, effect: str | None = None, term: str | None = None,
                  kind: str = 'camera') -> str | None:
    """The command of a next step (docs/compare.md, ``verdict.next``): add, remove or replace a term, a plug-in.

    Args:
        action: 'add', 'remove', 'replace' or 'plugin'.
        model_source: the model file, as the commands name it.
        effect: the effect added or taking a term's place.
        term: the model's term removed or replaced.
        kind: the plug-in's kind, 'camera' or 'gyro'.

    Returns:
        The command line, or None for another action.
    """
    commands = {'add': f'sofia model add {effect} --model {model_source}',
                'remove': f'sofia model remove {term} --model {model_source}',
                'replace': f'sofia model replace {term} {effect} --model {model_source}',
                'plugin': f'sofia effects new NAME --kind {kind}'}
    return commands.get(action)


def _strong_addition(candidates, best_name):
    """The physical effect an explained comparison with an observable above its floor should still add: ``best_name``
    (the verdict's choice within a competing set) where it qualifies, else the strongest refitted catalogue or
    plug-in candidate at EXPLAINED_ADDITION_DELTA_BIC; None if none does."""
    strong = [candidate for candidate in candidates if candidate['refined'] and not candidate['empirical']
              and candidate['detectable'] and candidate['delta_bic'] >= EXPLAINED_ADDITION_DELTA_BIC]
    chosen = next((candidate for candidate in strong if candidate['effect'] == best_name), None)
    return chosen or max(strong, key=lambda candidate: candidate['delta_bic'], default=None)


def _addition_clause(candidate):
    """Why an explained comparison should still add an effect, from its full refit."""
    return (f'{candidate["effect"]} lowers the BIC by {candidate["delta_bic"]:.0f} in a full refit, evidence the '
            f'RMS and structure tests alone do not show; add it')


def _change_clause(change):
    """Why a term of the model should go or make way, from its full refit."""
    if change['action'] == 'remove':
        return (f'{change["term"]} no longer pays for itself: without it the BIC falls by '
                f'{change["delta_bic"]:.0f}; remove it')
    terms = change['term'].split(',')
    several = len(terms) > 1
    return (f'{change["effect"]} explains what {" and ".join(terms)} {"do" if several else "does"}, better: the BIC '
            f'falls by {change["delta_bic"]:.0f} when it takes {"their" if several else "its"} place; '
            f'replace {"them" if several else "it"}')


def next_step(action: str, model_source: str, **names: str | None) -> NextStep:
    """The verdict's ``next``: the action, the effect and term it names, and the command that takes it.

    Args:
        action: 'add', 'remove', 'replace', 'plugin' or 'none'.
        model_source: the model file, as the command names it.
        **names: effect, term and kind, as model_command takes them.

    Returns:
        The action, effect, term and command (None where not named or for 'none').
    """
    return {'action': action, **{key: names.get(key) for key in ('effect', 'term')},
            'command': model_command(action, model_source, **names) if action != 'none' else None}


#: A verdict's first line is at most this long: the status and the one thing to do.
HEADLINE_CHARACTERS = 100


def headline(status: str, step: Mapping[str, str | None]) -> str:
    """'status: what to do: command' in at most HEADLINE_CHARACTERS, ending with the command or 'nothing to do'
    (the model file as .../NAME where the whole path would not fit, visibly cut; ``next.command`` has it whole).

    Args:
        status: the verdict's status.
        step: the verdict's ``next`` (next_step).

    Returns:
        The headline, at most HEADLINE_CHARACTERS long.
    """
    if step['action'] == 'none':
        return f'{status}: nothing to do'
    what = {'add': f'add {step["effect"]}', 'remove': f'remove {step["term"]}',
            'replace': f'replace {step["term"]} by {step["effect"]}', 'plugin': 'write a plug-in for the shape'}
    command = step['command']
    head, _, path = command.partition(' --model ')
    # Shorter and shorter: the whole command, the model file as .../NAME, the command without --model.
    forms = [f'{status}: {what[step["action"]]}: {command}', f'{status}: {command}']
    if path:
        forms += [f'{status}: {head} --model .../{path.rsplit("/", 1)[-1]}', f'{status}: {head}']
    return clipped_headline(next((form for form in forms if len(form) <= HEADLINE_CHARACTERS), forms[-1]))


def clipped_headline(line: str) -> str:
    """A headline cut to HEADLINE_CHARACTERS, with '...' where it was cut.

    Args:
        line: the whole headline.

    Returns:
        At most HEADLINE_CHARACTERS characters.
    """
    return line if len(line) <= HEADLINE_CHARACTERS else line[:HEADLINE_CHARACTERS - 3] + '...'


def judge(diagnostics: Diagnostics, consistency: Sequence[Mapping[str, Any]],
          candidates: Sequence[Mapping[str, Any]], degenerate: Iterable[Sequence[str]], best_name: str | None,
          after_best: tuple[Diagnostics, Sequence[Mapping[str, Any]]] | None, *, rms_arcsec: float | None,
          significant_delta_bic: float, model_source: str, competing: Iterable[CompetingSet] = (),
          members: Mapping[str, AfterMember] | None = None, change: Mapping[str, Any] | None = None,
          rms_arcsec_per_s: float | None = None, observable_keys: Iterable[str] = BAG_OBSERVABLE_KEYS,
          beyond_floor: Callable[[Mapping[str, Any]], bool] = beyond_bag_floor,
          measurements: int | None = None, fitted: Sequence[str] = (),
          unconstrained: Sequence[str] = ()) -> Verdict:
    """The verdict block: status, text, per-observable judgement, what is left after the best candidate, and the
    next step (``next``: add, remove or replace a term, write a plug-in, or none) and its ``headline``.

    One rule for bags and measurement sets: what differs is the source's, in ``diagnostics`` (each
    observable's ``explained``), ``beyond_floor`` (its rule for the RMS alone, named in the text) and
    ``observable_keys`` (what the JSON keeps of each observable). ``rms_arcsec_per_s`` is the total
    of a set's rate observables, the gain named where the set has no angles.

    Args:
        diagnostics: the residual diagnostics of the model's fit.
        consistency: the fitted terms that change between halves of the data.
        candidates: the candidates' entries of the JSON (compare.pipeline.candidate_entry).
        degenerate: the pairs of candidates the data cannot tell apart.
        best_name: the contender the verdict takes (competing.preferred_best), or None.
        after_best: the diagnostics and consistency of the refit with ``best_name``, or None.
        rms_arcsec: the total residual RMS ["], or None where the source has no angles.
        significant_delta_bic: the delta-BIC from which a candidate or a change counts.
        model_source: the model file, as the commands name it.
        competing: the competing sets of the ranking.
        members: what the comparison says with each refitted member of a competing set.
        change: the model's best structural change (a term to remove or replace), or None.
        rms_arcsec_per_s: the total RMS of a set's rate observables ["/s], or None.
        observable_keys: what the JSON keeps of each observable.
        beyond_floor: the source's rule for an observable's RMS alone.
        measurements: the number of measurements the fit is to (a bag's centroid axes, a set's rows), or None.
        fitted: the model's fitted parameters, by label.
        unconstrained: those the data cannot determine (no finite sigma), by label.

    Returns:
        The verdict block of the JSON (docs/compare.md): status, text, observables, inconsistent_terms,
        after_best, next and headline.
    """
    verdict = _judged(diagnostics, consistency, candidates, degenerate, best_name, after_best,
                      rms=(rms_arcsec, rms_arcsec_per_s), significant_delta_bic=significant_delta_bic,
                      model_source=model_source, competing=competing, members=members, change=change,
                      observable_keys=observable_keys, beyond_floor=beyond_floor)
    if verdict['status'] == 'explained' and measurements is not None and measurements <= len(fitted):
        # Nothing left to test: a fit of as many parameters as measurements meets every one of them, right or wrong.
        effects = sorted({label.rpartition('.')[0] for label in unconstrained or fitted})
        verdict.update(status='undetermined', next=next_step('none', model_source),
                       text=_undetermined_text(measurements, fitted, unconstrained))
        verdict['headline'] = clipped_headline(f'undetermined: the data cannot determine {", ".join(effects)}')
        return verdict
    verdict['headline'] = headline(verdict['status'], verdict['next'])
    return verdict


def _undetermined_text(measurements, fitted, unconstrained):
    """Why a fit of as many parameters as measurements explains nothing, and what to do (judge)."""
    named = ', '.join(unconstrained[:_NAMED]) + (f' (+{len(unconstrained) - _NAMED} more)'
                                                 if len(unconstrained) > _NAMED else '')
    which = (f'; {named} {"is" if len(unconstrained) == 1 else "are"} not determined: other values fit as well'
             if unconstrained else '')
    return (f'{measurements} measurement{"s" if measurements != 1 else ""} for {len(fitted)} fitted parameters: the '
            f'model meets every one whatever is wrong, so nothing is tested{which}; the fitted values are not a '
            f'calibration: add measurements (more turning points, maneuvers or stars), or fit fewer terms')


def _gain(rms, best):
    """The total RMS now and with the best candidate: in arcsec, or in arcsec/s where the source has no angles."""
    angle, rate = rms
    if angle is not None and best['rms_after_arcsec'] is not None:
        return f'RMS {angle:.3f}" -> {best["rms_after_arcsec"]:.3f}"'
    return f'RMS {rate:.4f}"/s -> {best["rms_after_arcsec_per_s"]:.4f}"/s'


def _judged(diagnostics, consistency, candidates, degenerate, best_name, after_best, *, rms,
            significant_delta_bic, model_source, competing, members, change, observable_keys, beyond_floor):
    observables = {name: {key: entry[key] for key in observable_keys if key in entry}
                   for name, entry in diagnostics.observables.items()}
    # A term of an axis that changes between halves is structure of that axis: the axis is not explained.
    prefixes = {name.split('.')[0] for name in observables}
    for entry in consistency:
        for name in _implicated_observables([entry], prefixes) & observables.keys():
            observables[name] = {**observables[name], 'explained': False, 'structure': [
                *observables[name]['structure'], f'{entry["param"]} changes with {entry["split"]}']}
    verdict = {'observables': observables, 'inconsistent_terms': [entry['param'] for entry in consistency],
               'after_best': None}
    problems = _problems(diagnostics, consistency, beyond_floor)
    worthwhile = change if change is not None and change['delta_bic'] >= significant_delta_bic else None
    if not problems:
        worst = max(observables.items(), key=lambda item: item[1]['ratio'], default=None)
        detail = f'; the largest RMS / floor is {worst[1]["ratio"]:.2f} ({worst[0]})' if worst else ''
        text = f'the model explains every observable to its noise, with no structure left and consistent terms{detail}'
        addition = _strong_addition(candidates, best_name)
        if addition is not None and (worthwhile is None or addition['delta_bic'] > worthwhile['delta_bic']):
            verdict.update(status='explained', text=f'{text}; but {_addition_clause(addition)}',
                           next=next_step('add', model_source, effect=addition['effect']))
        elif worthwhile is not None:
            verdict.update(status='explained', text=f'{text}; but {_change_clause(worthwhile)}',
                           next=next_step(worthwhile['action'], model_source, effect=worthwhile['effect'],
                                      term=worthwhile['term']))
        else:
            verdict.update(status='explained', text=f'{text}; nothing to do', next=next_step('none', model_source))
        return verdict
    best = next((c for c in candidates if c['effect'] == best_name), None)
    left = []
    if best is not None and after_best is not None:
        left_diagnostics, left_consistency = after_best
        left = _problems(left_diagnostics, left_consistency, beyond_floor)
        verdict['after_best'] = {'effect': best_name, 'unexplained': left_diagnostics.unexplained(),
                                 'inconsistent_terms': [entry['param'] for entry in left_consistency]}
    where = '; '.join(problems)
    first = ''
    if worthwhile is not None and (best is None or worthwhile['delta_bic'] > best['delta_bic']):
        first = f'. First: {_change_clause(worthwhile)} (more than adding any candidate gains)'
        verdict['next'] = next_step(worthwhile['action'], model_source, effect=worthwhile['effect'],
                                term=worthwhile['term'])
    if best is None or best['delta_bic'] < significant_delta_bic:
        kind = 'gyro' if all(name.startswith('gyro.') for name in diagnostics.unexplained()) else 'camera'
        verdict.update(status='unexplained', text=f'not explained: {where}; no catalogue effect explains it, and no '
                                                  f'empirical shape either: look at the report\'s residual plots{first}')
        verdict.setdefault('next', next_step('plugin', model_source, kind=kind))
        return verdict
    gain = _gain(rms, best)
    remaining = ('; with it every observable is explained' if not left else
                 f'; it does not close the loop: with it, {"; ".join(left)}')
    if best['empirical']:
        kind = _plugin_kind(best)
        verdict.update(status='unexplained', text=(
            f'not explained: {where}; no catalogue effect explains it, the empirical shape {best["effect"]} does '
            f'({gain}){remaining}. Turn it into physics: `sofia effects new NAME --kind {kind}` writes a plug-in '
            f'template; or keep the shape meanwhile: `sofia model add {best["effect"]} --model {model_source}`{first}'))
        verdict.setdefault('next', next_step('plugin', model_source, kind=kind))
        return verdict
    tied = [pair for pair in degenerate if best['effect'] in pair]
    rivals = competing_set_of(best['effect'], competing)
    if rivals is not None:
        choice = _rivals_clause(best['effect'], rivals, members or {best['effect']: {'status': 'not explained'}}, gain)
    elif tied:
        choice = f'the residual needs {" or ".join(tied[0])}; the data cannot choose'
    else:
        choice = f'missing effect {best["effect"]} ({gain})'
    advice = (f'; add it with `sofia model add {best["effect"]} --model {model_source}`' if not left else
              f'; add it and compare again: `sofia model add {best["effect"]} --model {model_source}`')
    verdict.update(status='missing_effect', text=f'not explained: {where}; {choice}{remaining}{advice}{first}')
    verdict.setdefault('next', next_step('add', model_source, effect=best['effect']))
    return verdict
