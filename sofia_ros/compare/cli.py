"""The `sofia compare` and `sofia model add` commands: tables on stdout, JSON and report written whole."""

from __future__ import annotations

import fcntl
import io
import json
import os
import argparse
import dataclasses
import sys
from collections.abc import Iterable, Mapping
from contextlib import contextmanager
from os import PathLike
from pathlib import Path
from typing import Any, TextIO

import numpy as np

from sofia_ros.cli_args import integer, number
from sofia_ros.errors import ConfigError
from sofia_ros.forked import usable_cores
from sofia_ros.output_files import (checked_output_directory, checked_output_file, current_umask, json_ready,
                                    output_target, write_text_atomically)
from sofia_ros.progress import Progress

__all__ = ['print_fitted_terms', 'spread_text', 'add_compare_arguments', 'run_compare', 'add_model_arguments',
           'run_model_add', 'edit_model_file', 'anchor_memory_bytes', 'DEFAULT_ANCHOR_S', 'MAX_ANCHOR_S',
           'MIN_ANCHOR_S']


#: Attitude anchors closer than ten frames of the slowest camera (0.2 s ticks, 1 s HIPO cadence and
#: longer imager exposures) are not determined by the centroids between them.
MIN_ANCHOR_S = 2.0
MAX_ANCHOR_S = 86400.0
#: The attitude anchors' spacing without --anchor-s (compare and design alike).
DEFAULT_ANCHOR_S = 30.0
#: Whole comparisons `--search` may make unless --search-rounds says otherwise.
_SEARCH_ROUNDS = 12
#: The fit's dense normal matrix and covariance: (3 per anchor + terms)^2 doubles, a few copies alive.
_DENSE_COPIES = 4
_TERM_COLUMNS = 100
#: Refuse a comparison whose design matrix would not fit in this share of the machine's memory.
_MEMORY_SHARE = 0.5
#: The reference camera every imager is compared against (6.2).
HIPO_CENTROIDS = '/hipo/centroids'


def add_compare_arguments(parser: argparse.ArgumentParser) -> None:
    """Arguments of `sofia compare`.

    Args:
        parser: the `compare` subcommand's parser, which gains them.
    """
    parser.add_argument('bag', help='bag directory of a campaign (sofia run alignment), or a measurement set '
                                    '(a .yaml/.yml file, docs/measurement-sets.md)')
    parser.add_argument('--model', required=True, help='model YAML (effects: ..., fit: true for fitted terms)')
    parser.add_argument('--json', help='write the comparison as JSON (docs/compare.md)')
    parser.add_argument('--report', help='write an HTML report with plots to this directory (ledger kept across runs)')
    parser.add_argument('--search', action='store_true',
                        help='search for the model the data ask for: add, remove and swap terms by BIC, refit, '
                             'repeat (docs/compare.md); prints the rounds, the final comparison and its equivalents')
    parser.add_argument('--search-rounds', type=integer(1, 20, 'rounds'),
                        help=f'with --search: whole comparisons the search may make (1-20, default {_SEARCH_ROUNDS})')
    parser.add_argument('--write-model', help='with --search: write the model found here (a copy of --model, edited)')
    parser.add_argument('--anchor-s', type=number(MIN_ANCHOR_S, MAX_ANCHOR_S, 's'), default=DEFAULT_ANCHOR_S,
                        help=f'spacing of the attitude anchors in s (default 30, at least {MIN_ANCHOR_S:g}: ten '
                             'frames of the slowest camera; they absorb the gyro random walk)')
    parser.add_argument('--no-cache', action='store_true',
                        help='decode the bag anew and keep no cache of its observations (by default they are kept in '
                             '<bag>/.sofia-cache or ~/.cache/sofia_ros; docs/compare.md)')
    parser.add_argument('--quiet', action='store_true',
                        help='no progress lines on stderr (warnings and errors are still written)')
    parser.add_argument('--jobs', type=integer(1, 64, 'worker processes'), default=usable_cores(),
                        help='fits that do not depend on each other (refits, judgements, the fit from the given '
                             'values) run in up to this many forked processes at once (default: the usable cores, '
                             f'{usable_cores()} here); the results are the same with 1; a measurement set, '
                             'compared in a second, takes one process')


def add_model_arguments(parser: argparse.ArgumentParser) -> None:
    """Arguments of `sofia model add|remove|replace`.

    Args:
        parser: the `model` subcommand's parser, which gains them.
    """
    parser.add_argument('action', choices=('add', 'remove', 'replace'),
                        help='add: put an effect into a model as a fitted term; remove: take a term out; '
                             'replace: take a term out and put another in its place (`replace OLD NEW`)')
    parser.add_argument('effect', help='effect name (sofia effects); for replace, the term(s) to take out, '
                                       'comma-separated')
    parser.add_argument('replacement', nargs='?', help='replace: the effect that takes its place')
    parser.add_argument('--model', required=True, help='model YAML to edit in place')


def _format_params(params, sigma, units):
    def one(name, value):
        spread = 'unconstrained' if sigma[name] is None else f'+- {sigma[name]:.2g}'
        return f'{name} = {value:.4g} {spread} {units.get(name, "")}'.rstrip()

    return ', '.join(one(name, value) for name, value in params.items())


def print_comparison(document: Mapping[str, Any], out: TextIO) -> None:
    """The ten-second table: terms, correlations, ledger, candidates, degeneracies, where the model fails.

    Args:
        document: the comparison's JSON document (docs/compare.md), JSON-ready.
        out: where the table is printed.
    """
    counts = ', '.join(f'{camera.upper()} {count}' for camera, count in document['observations'].items())
    print(f'sofia compare: {document["bag"]} against {document["model"]}', file=out)
    outliers = ', '.join(f'{camera.upper()} {count}' for camera, count in document['outliers_by_camera'].items()
                         if count)
    print(f'  centroids: {counts}; noise floor {document["noise_floor_arcsec"]:.3f}" per axis (centroid scatter '
          f'of locked frames); outliers beyond 5 sigma (down-weighted, counted in the RMS): '
          f'{outliers or "none"}', file=out)
    if document['terms']:
        print_fitted_terms(document['terms'], out)
        labels, matrix = document['correlation']['params'], np.array(document['correlation']['matrix'], dtype=float)
        strong = [(labels[i], labels[j], matrix[i, j]) for i in range(len(labels)) for j in range(i + 1, len(labels))
                  if np.isfinite(matrix[i, j]) and abs(matrix[i, j]) >= 0.9]
        for first, second, value in strong:
            print(f'  correlated: {first} ~ {second}  r = {value:+.3f}', file=out)
    cameras = [camera for camera in ('hipo', 'fpi', 'ffi', 'wfi') if camera in document['residual_rms_arcsec']]
    print('ledger: residual RMS per axis ["] as terms are fitted', file=out)
    print(f'  {"step":<40} {"total":>7}' + ''.join(f' {camera.upper():>7}' for camera in cameras), file=out)
    for row in document['ledger']:
        rms = row['residual_rms_arcsec']
        name = row['term'] if row is document['ledger'][0] else '+ ' + row['term']
        print(f'  {name:<40} {rms["total"]:>7.3f}' + ''.join(f' {rms[camera]:>7.3f}' for camera in cameras), file=out)
    print(f'candidates (catalogue effects not in the model, empirical shapes), best first; significant at delta-BIC >= '
          f'{document["significant_delta_bic"]:g}:', file=out)
    for candidate in [c for c in document['candidates'] if c['detectable']][:6]:
        mark = '*' if candidate['delta_bic'] >= document['significant_delta_bic'] else ' '
        print(f' {mark}{candidate["effect"]:<28} dBIC {candidate["delta_bic"]:>10.1f}  RMS after '
              f'{candidate["rms_after_arcsec"]:.3f}"  {"refit" if candidate["refined"] else "linear"}', file=out)
        if mark == '*':
            print(f'      {_format_params(candidate["params"], candidate["sigma"], candidate["units"])}', file=out)
    if document['unobservable']:
        print(f'  not observable in this campaign: {", ".join(document["unobservable"])}', file=out)
    from sofia_ros.compare.competing import competing_lines

    for line in competing_lines(document, 'campaign'):
        print(line, file=out)
    if 'star_hop' in document:
        _print_star_hop(document['star_hop'], out)
    _print_diagnostics(document, out)
    _print_verdict(document, out)


def _print_star_hop(analysis, out):
    """Table 6.7 (drift-corrected and short moves against the catalogue), Fig. 6.11's lines, Fig. 6.4, 6.3's drift."""
    print('star hop: measured (gyros + HIPO, drift of the holds removed, 6.3) against catalogue distances '
          '(refracted, Table D.3);', file=out)
    print('  short move: gyros + the FPI just before and after the move (6.7-6.8, Table D.6) against the catalogue '
          'at those times', file=out)
    print(f'  {"move":<24} {"measured":>11} {"catalogue":>11} {"deviation":>10} {"refraction":>11} '
          f'{"short move":>11} {"deviation":>10} {"sigma":>6} {"interval":>8}', file=out)
    for move in analysis['moves']:
        name = f'{move["from"]} -> {move["to"]}'
        short = '' if move['short_move_arcsec'] is None else (
            f' {move["short_move_arcsec"]:>10.1f}" {move["short_move_deviation_arcsec"]:>+9.2f}" '
            f'{move["short_move_sigma_arcsec"]:>5.2f}" {move["short_move_interval_s"]:>6.0f} s')
        print(f'  {name:<24} {move["measured_arcsec"]:>10.1f}" {move["catalogue_arcsec"]:>10.1f}" '
              f'{move["deviation_arcsec"]:>+9.2f}" {move["refraction_change_arcsec"]:>+10.1f}"{short}', file=out)
    for label, fit in (('', analysis['deviation_fit']), ('short moves: ', analysis['short_move_fit'])):
        if fit:
            print(f'  {label}deviation = {fit["intercept_arcsec"]:+.2f}" + {fit["slope_arcsec_per_deg"]:+.3f}"/deg x '
                  f'distance (+- {fit["slope_sigma"]:.3f}; a scale error of {fit["scale_error_ppm"]:+.0f} ppm; '
                  f'Fig. 6.11), rms about the line {fit["rms_about_fit_arcsec"]:.2f}"', file=out)
    flexure = analysis['imager_flexure']
    if flexure:
        for camera in ('fpi', 'ffi'):
            measured = flexure['fit'][camera]['change_23_to_60_deg_arcsec']
            fem = flexure['fem_change_23_to_60_deg_arcsec'][camera]
            print(f'  {camera.upper()} against HIPO, 23 -> 60 deg: measured ({measured[0]:+.2f}", {measured[1]:+.2f}") '
                  f'FEM ({fem[0]:+.2f}", {fem[1]:+.2f}")  (dEL, dXEL; Fig. 6.4)', file=out)
    _print_centroid_drift(analysis['centroid_drift'], out)


def _print_centroid_drift(holds, out):
    """6.3's residual FPI centroid drift: the range over the holds, and every sinusoid the BIC kept."""
    if not holds:
        return
    column = [hold['column']['drift_px_per_min'] for hold in holds]
    row = [hold['row']['drift_px_per_min'] for hold in holds]
    sigma = [hold[axis]['drift_sigma'] for hold in holds for axis in ('column', 'row')
             if hold[axis]['drift_sigma'] is not None]
    spread = f' (+- {min(sigma):.2f}-{max(sigma):.2f})' if sigma else ''
    selected = [hold for hold in holds if hold['row']['sinusoid']]
    print(f'  FPI centroid drift in {len(holds)} holds (6.3): column {min(column):+.2f} to {max(column):+.2f} '
          f'px/min, row {min(row):+.2f} to {max(row):+.2f} px/min{spread}; row sinusoid (delta-BIC >= 6 against '
          f'the line) in {len(selected)} of {len(holds)}', file=out)
    for hold in selected:
        sine = hold['row']['sinusoid']
        print(f'    {hold["star"]} (hold at {hold["hold_start_s"]:.0f} s): row '
              f'{hold["row"]["drift_px_per_min"]:+.2f} {spread_text(hold["row"]["drift_sigma"], ".2f")} px/min + '
              f'sinusoid of {sine["period_s"]:.0f} '
              f'{spread_text(sine["period_sigma"], ".0f")} s, {sine["amplitude_px"]:.2f} '
              f'{spread_text(sine["amplitude_sigma"], ".2f")} px, phase {sine["phase_deg"]:+.0f} '
              f'{spread_text(sine["phase_sigma"], ".0f")} deg at {hold["reference_time_s"]:.0f} s', file=out)


def spread_text(sigma: float | None, spec: str = '.2g') -> str:
    """'+- sigma' in ``spec``, or 'unconstrained' for a parameter the data do not determine (sigma null).

    Args:
        sigma: the parameter's standard deviation, or None.
        spec: the format specification of the number.

    Returns:
        The text.
    """
    return 'unconstrained' if sigma is None else f'+- {sigma:{spec}}'


def print_fitted_terms(terms: Iterable[Mapping[str, Any]], out: TextIO) -> None:
    """The fitted terms' table of a comparison, bag or measurement set.

    Args:
        terms: the JSON's ``terms`` (effect, param, value, sigma, unit each).
        out: where the table is printed.
    """
    print('fitted terms:', file=out)
    for term in terms:
        print(f'  {term["effect"] + "." + term["param"]:<44} {term["value"]:>12.4f} '
              f'{spread_text(term["sigma"], "<9.4f"):<12} {term["unit"]}', file=out)


def _print_diagnostics(document, out):
    """Every observable against its floor, then the strongest structure and the inconsistent terms."""
    from sofia_ros.compare.diagnostics import distinct_findings

    observables = document['verdict']['observables']
    print('observables: residual RMS against its own floor (camera axes: centroid noise; gyro axes: the anchor '
          'walk the gyro noise allows)', file=out)
    cells = [f'{name} {entry["rms_arcsec"]:.3f}/{entry["floor_arcsec"]:.3f}"{"" if entry["explained"] else " !"}'
             for name, entry in observables.items()]
    for start in range(0, len(cells), 4):
        print('  ' + '   '.join(f'{cell:<26}' for cell in cells[start:start + 4]).rstrip(), file=out)
    signature = document['signature']
    findings = distinct_findings([*signature['trends'], *signature['periods']])
    if findings:
        print(f'structure in the residual (family-wise significance over {signature["tests_run"]} tests; '
              f'structure from {signature["detection_sigma"]:g} sigma):', file=out)
    for finding in findings[:5]:
        if 'period_s' in finding:
            what = f'period {finding["period_s"]:.4g} s'
        else:
            same = finding['equivalent_variables']
            what = f'follows {finding["variable"]}' + (f' (= {", ".join(same)} here)' if same else '')
        print(f'  {finding["observable"]:<9} {what:<58} {finding["amplitude_arcsec"]:7.3f}" '
              f'{finding["significance_sigma"]:5.1f} sigma', file=out)
    for entry in document['consistency'][:3]:
        print(f'  {entry["param"]} changes with {entry["split"]}: {entry["values"][0]:.4g} +- {entry["sigmas"][0]:.2g} '
              f'against {entry["values"][1]:.4g} +- {entry["sigmas"][1]:.2g} ({entry["significance_sigma"]:.0f} sigma)',
              file=out)


def _print_verdict(document, out):
    verdict = document['verdict']
    print(f'verdict: {verdict["headline"]}', file=out)
    print(f'  why: {verdict["text"]}', file=out)


def run_compare(args: argparse.Namespace, out: TextIO) -> int:
    """`sofia compare`: fit, rank, print; then write JSON and report whole.

    Args:
        args: the parsed arguments of `sofia compare` (add_compare_arguments).
        out: where the tables are printed.

    Returns:
        The exit code, 0.

    Raises:
        ConfigError: the options contradict each other or name a missing directory, a directory for --json or a
            file for --report.
    """
    from sofia_ros.compare.cache import ObservationCache
    from sofia_ros.compare.observations import observation_cache
    from sofia_ros.compare.run import compare_bag
    from sofia_ros.config import load_effect_config

    if args.write_model and not args.search:
        raise ConfigError('--write-model writes the model --search finds; add --search')
    model = load_effect_config(args.model)
    for target in (args.json, args.report):
        if target and not Path(target).resolve().parent.exists():
            raise ConfigError(f'the directory of {target} does not exist; create it first')
    if args.json and Path(args.json).is_dir():
        raise ConfigError(f'--json {args.json} is a directory; give a file name, '
                          f'e.g. {Path(args.json) / "compare.json"}')
    _check_bag_arguments(args.bag, args.anchor_s, _warn)
    _check_outputs(args)
    if str(args.bag).lower().endswith(('.yaml', '.yml')):
        from sofia_ros.measurements.report import run_set_compare

        if args.search:
            return _search_set(args, model, out)
        return run_set_compare(args, out, model)
    progress = Progress.silent() if args.quiet else Progress(sys.stderr, prefix='sofia compare')
    with observation_cache(None if args.no_cache else ObservationCache(warn=_warn, progress=progress)):
        if args.search:
            result, found = _search(args, model, progress)
            document = json_ready(_with_search(result.document, found, args.model))
        else:
            result = compare_bag(args.bag, model, anchor_spacing_s=args.anchor_s, progress=progress, jobs=args.jobs)
            document = json_ready(result.document)
    print_comparison(document, out)
    if args.search:
        _print_search(document['search'], out)
    # The report first: a report the disk cannot hold leaves no JSON behind either.
    if args.report:
        from sofia_ros.compare.report import write_report

        path = write_report(result, document, args.report)
        print(f'report: {path}', file=out)
    if args.json:
        write_text_atomically(args.json, json.dumps(document, indent=2) + '\n')
    return 0


def _check_outputs(args: argparse.Namespace) -> None:
    """ConfigError in one line, before any work, for an output that cannot be written or would replace an input: the
    model, the bag or a file in its folder (--write-model may be the model: the search edits it), another output, or
    a report folder whose ledger.json is not a ledger."""
    from sofia_ros.compare.report import read_ledger

    for option, value in (('--json', args.json), ('--report', args.report), ('--write-model', args.write_model)):
        if value == '':
            raise ConfigError(f'{option} is given an empty path; give a file name or leave {option} out')
    bag = {'the bag': args.bag}
    # In the order they are written: the report first.
    if args.report:
        checked_output_directory('--report', args.report, bag)
        read_ledger(args.report)
    if args.json:
        checked_output_file('--json', args.json, {**bag, 'the model': args.model, '--write-model': args.write_model,
                                                  '--report': args.report})
    if args.write_model:
        checked_output_file('--write-model', args.write_model, bag)
    if args.search_rounds is not None and not args.search:
        raise ConfigError('--search-rounds limits the rounds of --search; add --search')


def _warn(line):
    """A warning of `sofia compare`: one line on stderr, also with --quiet."""
    print(line, file=sys.stderr)


def _search(args, model, progress):
    """--search on a bag: the rounds of compare.search on observations read once."""
    from sofia_ros.compare.observations import read_observations
    from sofia_ros.compare.run import compare_observations

    if args.write_model:
        output_target(args.write_model)
    progress.phase('reading the bag')
    observations = read_observations(args.bag)
    return _searched(args, model, progress, observations,
                     lambda obs, trial: compare_observations(obs, trial, anchor_spacing_s=args.anchor_s,
                                                             progress=progress, jobs=args.jobs))


def _search_set(args, model, out):
    """--search on a measurement set: the same search over compare_measurement_set, printed and written as a set's
    comparison is (measurements.report)."""
    from sofia_ros.measurements.compare import compare_measurement_set
    from sofia_ros.measurements.report import print_set_comparison, write_set_report
    from sofia_ros.measurements.validate import load_measurement_set

    if args.write_model:
        output_target(args.write_model)
    progress = Progress.silent() if args.quiet else Progress(sys.stderr, prefix='sofia compare')
    result, found = _searched(args, model, progress, load_measurement_set(args.bag), compare_measurement_set)
    document = json_ready(_with_search(result.document, found, args.model))
    print_set_comparison(document, out)
    _print_search(document['search'], out)
    if args.report:
        print(f'report: {write_set_report(result, document, args.report)}', file=out)
    if args.json:
        write_text_atomically(args.json, json.dumps(document, indent=2) + '\n')
    return 0


def _searched(args, model, progress, data, compare):
    """The search (compare.search.search_model) of ``data`` with ``compare``; the model written where asked.

    Returns:
        The last round's comparison and the document's ``search`` block.
    """
    from sofia_ros.compare.search import search_model

    # Every model the search compares is named by the file that will hold the one it finds, so that the answer's
    # JSON, report and next command name that file (they named the model given, which lacks what the search added).
    named = dataclasses.replace(model, source=str(args.write_model)) if args.write_model else model
    result, found, rounds, equivalent = search_model(data, named, compare, rounds=args.search_rounds or _SEARCH_ROUNDS,
                                                     progress=progress.phase)
    given = set(model.fitted)
    added, removed = sorted(found.fitted - given), sorted(given - found.fitted)
    written = None
    if args.write_model:
        written = str(args.write_model)
        if Path(args.write_model).resolve() != Path(args.model).resolve():
            write_text_atomically(args.write_model, model.text)
        edit_model_file(args.write_model, add=added, remove=removed)
    return result, {'rounds': rounds, 'fitted': sorted(found.fitted), 'added': added, 'removed': removed,
                    'status': result.document['verdict']['status'], 'equivalent': equivalent,
                    'written': written}


def _with_search(document, found, given_model):
    """The answer's document with the search block; where the search changed the model and wrote it nowhere, the
    verdict's next command first brings the model given to the one found (its commands would take the next step on
    a model without the search's changes), and its text says so."""
    from sofia_ros.compare.verdict import clipped_headline

    document = {**document, 'search': found}
    changes = [f'sofia model add {name} --model {given_model}' for name in found['added']]
    changes += [f'sofia model remove {name} --model {given_model}' for name in found['removed']]
    if found['written'] is not None or not changes:
        return document
    verdict = dict(document['verdict'])
    difference = ' '.join([*(f'+{name}' for name in found['added']), *(f'-{name}' for name in found['removed'])])
    verdict['text'] = (f'of the model the search found ({given_model} {difference}; --write-model F.yaml writes it): '
                       f'{verdict["text"]}')
    if verdict['next']['command'] is not None:
        step = {**verdict['next'], 'command': ' && '.join([*changes, verdict['next']['command']])}
        verdict.update(next=step, headline=clipped_headline(f'{verdict["status"]}: {step["command"]}'))
    return {**document, 'verdict': verdict}


def _print_search(search, out):
    print('search: the model the data ask for (BIC; rounds of linearized search and full refit)', file=out)
    for entry in search['rounds']:
        moves = '; '.join(entry['moves']) or 'no change'
        # A set of rates alone (Edwards' Earth-rate records) has no angle residual: its RMS is null.
        rms = 'no angle' if entry['rms_arcsec'] is None else f'{entry["rms_arcsec"]:.3f}"'
        print(f'  round {entry["round"]}: {entry["status"]:<15} RMS {rms}  -> {moves}', file=out)
        if entry['ends']:
            print(f'  the search ends here: {entry["ends"]}', file=out)
    change = ', '.join([*(f'+{name}' for name in search['added']), *(f'-{name}' for name in search['removed'])])
    print(f'  found: {change or "the model as given"} ({search["status"]})', file=out)
    for entry in search['equivalent'][:5]:
        print(f'  equivalent (within delta-BIC 10): {entry["model"]} (delta-BIC {entry["delta_bic"]:+.1f})', file=out)
    if search['written']:
        print(f'  model written: {search["written"]}', file=out)


def anchor_memory_bytes(duration_s: float, anchor_s: float) -> float:
    """Memory the fit's dense matrices take for a record of ``duration_s`` with anchors every ``anchor_s``.

    Args:
        duration_s: the record's length (s).
        anchor_s: the spacing of the attitude anchors (s).

    Returns:
        The bytes, about.
    """
    columns = 3 * (duration_s / anchor_s + 1.0) + _TERM_COLUMNS
    return _DENSE_COPIES * 8 * columns ** 2


def _check_bag_arguments(bag, anchor_s, warn):
    """Refuse an --anchor-s whose dense fit matrices would not fit in half of this machine's memory;
    warn when the bag has no HIPO centroids (the imagers are then fitted without their reference)."""
    from sofia_ros.bag import BagReader
    from sofia_ros.errors import BagError
    from sofia_ros.topics import DEFAULT_TICK_NS

    # From metadata.yaml alone: opening the bag (its summary CRCs, rosbags' own metadata reading) cost about a second
    # of every compare, the cached ones too, and compare_bag checks the files when it reads them or the cache's key.
    try:
        counts = BagReader(bag).listed_topic_counts
    except BagError:
        return  # compare_bag names what is wrong with the bag itself
    if '/clock' not in counts:
        return
    names, duration_s = set(counts), counts['/clock'] * DEFAULT_TICK_NS / 1e9
    if anchor_s > duration_s:
        # The gyro axes are judged on the anchors' innovations, which need two intervals: a day's spacing on a short
        # flight made their lines vanish from the verdict without a word.
        raise ConfigError(f'--anchor-s {anchor_s:g} is longer than the {duration_s:.0f} s record, which leaves fewer '
                          f'than two anchor intervals and the gyro axes unjudged; give at most {duration_s / 2.0:.0f} s')
    needed = anchor_memory_bytes(duration_s, anchor_s)
    available = os.sysconf('SC_PAGE_SIZE') * os.sysconf('SC_PHYS_PAGES') * _MEMORY_SHARE
    if needed > available:
        raise ConfigError(f'--anchor-s {anchor_s:g} needs about {needed / 2**30:.1f} GiB for {duration_s:.0f} s of '
                          f'record (usable here: {available / 2**30:.1f} GiB); choose a larger --anchor-s')
    if HIPO_CENTROIDS not in names and any(name.endswith('/centroids') for name in names):
        warn(f'sofia compare: warning: {bag} has no {HIPO_CENTROIDS}: the reference camera is missing, so the '
             'imagers are fitted against the gyros alone and HIPO-relative terms are not observable')


@contextmanager
def _edit_lock(target):
    """Hold an exclusive flock on a sidecar file beside ``target`` (concurrent `sofia model add` wait in turn)."""
    lock_path = target.with_name(f'.{target.name}.lock')
    try:
        descriptor = os.open(lock_path, os.O_RDWR | os.O_CREAT, 0o666 & ~current_umask())
    except OSError as err:
        raise ConfigError(f'cannot lock {target} for editing ({lock_path}: {err.strerror}); '
                          'is its directory writable?') from err
    try:
        fcntl.flock(descriptor, fcntl.LOCK_EX)
        yield
    finally:
        os.close(descriptor)


def _round_trip_yaml():
    from ruamel.yaml import YAML

    editor = YAML()  # round trip: comments, order, quotes and flow style stay as the user wrote them
    editor.preserve_quotes = True
    editor.width = 4096  # folded text (description: >) is kept as written, not re-wrapped at 80 columns
    return editor


def run_model_add(args: argparse.Namespace, out: TextIO) -> int:
    """`sofia model add|remove|replace EFFECT [NEW] --model M.yaml`: one edit of a model file (edit_model_file).

    Args:
        args: the parsed arguments of `sofia model` (add_model_arguments).
        out: where the edit is reported.

    Returns:
        The exit code, 0.

    Raises:
        ConfigError: replace without its NEW effect, or add/remove with one.
    """
    from sofia_ros.effects import get_effect

    path = Path(args.model)
    if args.action == 'replace':
        if not args.replacement:
            raise ConfigError('usage: sofia model replace OLD NEW --model M.yaml (NEW takes the place of OLD)')
        old = tuple(get_effect(name).name for name in args.effect.split(','))
        new = get_effect(args.replacement).name
        if not 1 <= len(old) <= 2 or len(set(old)) != len(old) or new in old:
            raise ConfigError(f'sofia model replace takes one or two different terms to take out and another to put '
                              f'in (OLD[,OLD2] NEW), got {args.effect} {args.replacement}')
        kept = edit_model_file(path, add=(new,), remove=old)
        print(f'{path}: {" and ".join(old)} replaced by {new} as a fitted term ({_starting(new, kept)}); '
              'rerun sofia compare', file=out)
        return 0
    if args.replacement:
        raise ConfigError(f'sofia model {args.action} takes one effect; did you mean `sofia model replace '
                          f'{args.effect} {args.replacement}`?')
    name = get_effect(args.effect).name
    if args.action == 'remove':
        edit_model_file(path, remove=(name,))
        print(f'{path}: {name} removed; rerun sofia compare', file=out)
        return 0
    kept = edit_model_file(path, add=(name,))
    print(f'{path}: {name} added as a fitted term ({_starting(name, kept)}); rerun sofia compare', file=out)
    return 0


def _starting(name: str, kept: set[str]) -> str:
    """Where a term put in starts: the values the file gave it (a fixed effect made fitted), or the thesis' own."""
    return 'starting at its values in the file' if name in kept else 'starting at its thesis defaults'


def _spelled_as_in(effects: Mapping[str, Any], name: str) -> str:
    """``name`` as ``effects`` spells the same term (an empirical term's period_095s for period_95s), else itself."""
    from sofia_ros.effects.empirical import term_identity

    identity = term_identity(name)
    return next((given for given in effects if term_identity(given) == identity), name)


def edit_model_file(path: str | PathLike[str], *, add: Iterable[str] = (), remove: Iterable[str] = ()) -> set[str]:
    """Take the effects ``remove`` out of a model file and put ``add`` in as fitted terms, in one edit.

    The file is edited, not regenerated: comments, order and style stay (ruamel.yaml round
    trip); it is replaced atomically, a symlink is written through to its regular-file target
    with the target's mode, and concurrent edits wait for each other on a sidecar lock.

    Args:
        path: the model file.
        add: the effects put in as fitted terms.
        remove: the effects taken out.

    Returns:
        The effects of ``add`` that the file held with values of their own (fixed), which they keep.

    Raises:
        ConfigError: the file is missing or not valid YAML, an effect to remove is not in it, one to add is fitted
            already, or the edited model is not valid.
    """
    from ruamel.yaml.comments import CommentedMap
    from ruamel.yaml.error import YAMLError

    from sofia_ros.config import load_effect_config, parse_effect_config

    path = Path(path)
    target = output_target(path)
    if not target.exists():
        raise ConfigError(f'cannot read {path}: no such file; check the path')
    if any(target.parent.glob('*.mcap')):
        # A bag's truth.yaml or model.yaml is what the run recorded: edited, the bag no longer said what it flew.
        raise ConfigError(f'{path} is a file of the bag {target.parent}, recorded with it; copy it out of the bag and '
                          'edit the copy')
    with _edit_lock(target):
        text = load_effect_config(target).text
        editor = _round_trip_yaml()
        try:
            document = editor.load(text)
        except YAMLError as err:
            raise ConfigError(f'{path}: not valid YAML ({str(err).splitlines()[0]}); fix the syntax') from err
        if document is None:
            document = CommentedMap()
        if document.get('effects') is None:
            document['effects'] = CommentedMap()
        effects = document['effects']
        for name in remove:
            name = _spelled_as_in(effects, name)
            if name not in effects:
                raise ConfigError(f'{path} has no {name}; nothing to remove (its effects: '
                                  f'{", ".join(effects) or "none"})')
            del effects[name]
        kept = set()
        for name in add:
            name = _spelled_as_in(effects, name)
            current = effects.get(name)
            if isinstance(current, dict) and current.get('fit'):
                raise ConfigError(f'{path} already fits {name}; nothing to add')
            if isinstance(current, dict):
                if any(key != 'fit' for key in current):
                    kept.add(name)
                if any(other is current for key, other in effects.items() if key != name):
                    # A YAML anchor shared with another effect (`tracker_drift: *b`): fitting one fitted both.
                    current = effects[name] = CommentedMap(current.items())
                current['fit'] = True
            else:
                effects[name] = CommentedMap([('fit', True)])
        buffer = io.StringIO()
        editor.dump(document, buffer)
        new_text = buffer.getvalue()
        parse_effect_config(new_text, str(path))
        write_text_atomically(target, new_text)
    return kept
