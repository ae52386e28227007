"""Printed table, JSON and HTML report of a measurement-set comparison (the bag comparison's layout)."""

from __future__ import annotations

import argparse
import html
import json
from pathlib import Path
from typing import Any, TextIO

import numpy as np

from sofia_ros.compare.cli import print_fitted_terms, spread_text
from sofia_ros.config import EffectConfig
from sofia_ros.output_files import json_ready, write_text_atomically

__all__ = ['print_set_comparison', 'write_set_report', 'run_set_compare']


def _rms_text(rms):
    return ', '.join(f'{key} {value:.3f}' for key, value in rms.items() if value is not None)


def print_set_comparison(document: dict, out: TextIO) -> None:
    """The ten-second table of a measurement-set comparison.

    Args:
        document: the comparison's JSON document (json_ready).
        out: where the table goes.
    """
    print(f'sofia compare: {document["measurement_set"]} against {document["model"]}', file=out)
    if document['title']:
        print(f'  {document["title"]}', file=out)
    tables = '; '.join(f'{name}: {entry["kind"]} x {entry["rows"]}' + (' (drift removed)' if entry['drift_removed']
                                                                        else '')
                       for name, entry in document['observations'].items())
    floor = document['noise_floor_arcsec']
    floor_text = f'{floor:.3f}"' if floor is not None else ''
    if document.get('noise_floor_arcsec_per_s') is not None:
        floor_text += (' ' if floor_text else '') + f'{document["noise_floor_arcsec_per_s"]:.4f} "/s (= deg/h)'
    print(f'  tables: {tables}; noise floor {floor_text} (the stated sigmas)', file=out)
    if document['terms']:
        print_fitted_terms(document['terms'], out)
    for name, reason in document['not_observable_fitted_terms'].items():
        print(f'  {name} (fitted in the model) is not observable here: {reason}', file=out)
    print('ledger: residual RMS as terms are fitted', file=out)
    for index, row in enumerate(document['ledger']):
        name = row['term'] if index == 0 else '+ ' + row['term']
        parts = [_rms_text(row['residual_rms_arcsec']) + ' ["]' if row['residual_rms_arcsec'] else '',
                 _rms_text(row['residual_rms_arcsec_per_s']) + ' ["/s]' if row['residual_rms_arcsec_per_s'] else '']
        print(f'  {name:<48} {"  ".join(part for part in parts if part)}', file=out)
    print(f'candidates (catalogue effects not in the model), best first; significant at delta-BIC >= '
          f'{document["significant_delta_bic"]:g}:', file=out)
    for candidate in [c for c in document['candidates'] if c['detectable']][:6]:
        mark = '*' if candidate['delta_bic'] >= document['significant_delta_bic'] else ' '
        after = candidate['rms_after_arcsec']
        after_text = f'{after:.3f}"' if after is not None else f'{candidate["rms_after_arcsec_per_s"]:.4f} "/s'
        print(f' {mark}{candidate["effect"]:<28} dBIC {candidate["delta_bic"]:>9.1f}  RMS after {after_text}  '
              f'{"refit" if candidate["refined"] else "linear"}', file=out)
        if mark == '*':
            params = ', '.join(f'{key} = {value:.4g} {spread_text(candidate["sigma"].get(key))} {candidate["units"][key]}'
                               for key, value in candidate['params'].items())
            print(f'      {params}', file=out)
    hidden = [c for c in document['candidates'] if not c['detectable']]
    if hidden:
        print('  not observable in this set:', file=out)
        reasons = {}
        for candidate in hidden:
            reasons.setdefault(candidate.get('reason', ''), []).append(candidate['effect'])
        for reason, names in reasons.items():
            print(f'    {", ".join(names)}: {reason}', file=out)
    from sofia_ros.compare.competing import competing_lines

    for line in competing_lines(document, 'set'):
        print(line, file=out)
    _print_rows(document, out)
    for name, table in document.get('earth_rate', {}).items():
        _print_earth_rate(name, table, out)
    _print_structure(document['signature'], out)
    verdict = document['verdict']
    print(f'verdict: {verdict["headline"]}', file=out)
    print(f'  why: {verdict["text"]}', file=out)
    for name, entry in verdict['observables'].items():
        unit = 'arcsec_per_s' if 'rms_arcsec_per_s' in entry else 'arcsec'
        mark = '"/s' if unit == 'arcsec_per_s' else '"'
        print(f'  {name:<24} RMS {entry[f"rms_{unit}"]:.4g}{mark} floor {entry[f"floor_{unit}"]:.4g}{mark} '
              f'ratio {entry["ratio"]:.2f} {"explained" if entry["explained"] else "NOT explained"}', file=out)


def _print_structure(signature, out):
    """Each observable's trend against its own measured value (the distance, for star pairs; Fig. 6.11)."""
    if signature['trends']:
        print(f'structure in the residual (family-wise significance over {signature["tests_run"]} tests; '
              f'structure from {signature["detection_sigma"]:g} sigma):', file=out)
    for trend in signature['trends']:
        print(f'  {trend["observable"]} follows {trend["variable"]:<24} {trend["amplitude_arcsec"]:8.3f}" '
              f'{trend["significance_sigma"]:5.1f} sigma', file=out)


def _print_earth_rate(name, table, out):
    """Table 5.7 of the set's mean rates: theory and apparent biases at the stated and the least-squares heading."""
    def row(label, values):
        print(f'  {label:<44} ' + ' '.join(f'{values[axis]:>9.4f}' for axis in ('el', 'xel', 'los')), file=out)

    print(f'earth rate ({name}): mean of the rows in TARF against eqs. 4.1-4.3 [deg/h]      EL       XEL       LOS',
          file=out)
    row('measured (TARF)', table['measured'])
    row(f'theory at the stated heading {table["heading_deg"]:.2f} deg', table['theoretical'])
    row('apparent biases at the stated heading', table['deviation'])
    row(f'theory at the least-squares heading {table["best_fit_heading_deg"]:.2f} deg',
        table['theoretical_at_best_fit_heading'])
    row('apparent biases at the least-squares heading', table['deviation_at_best_fit_heading'])
    print(f'  a heading error and constant biases are degenerate on a braked telescope ({" ~ ".join(table["degenerate_pair"])}, '
          '5.2.4): any heading explains the means with other biases', file=out)


def _print_rows(document, out):
    best = next((c['effect'] for c in document['candidates'] if c['refined']), None)
    print(f'rows: measured, residual against the fitted model{" and after " + best if best else ""}', file=out)
    for row in document['rows']:
        after = '' if row['residual_after_best'] is None else f' {row["residual_after_best"]:>+10.3f}'
        print(f'  {row["table"]:<34} {row["label"]:<8} {row["observable"]:<22} {row["measured"]:>12.4f} '
              f'{row["residual"]:>+10.3f}{after}  (sigma {row["sigma"]:g})', file=out)


def write_set_report(result: Any, document: dict, directory: str | Path) -> Path:
    """index.html with the residuals against distance (Fig. 6.11) or per row, before and after the best candidate.

    Args:
        result: the SetCompareResult (measurements.compare).
        document: its JSON document (json_ready).
        directory: where the report goes (created if needed).

    Returns:
        The path of index.html.
    """
    import matplotlib

    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    rows = document['rows']
    images = []
    for table in result.measurement_set.tables:
        entries = [row for row in rows if row['table'] == table.name]
        residual = np.array([row['residual'] for row in entries])
        after = [row['residual_after_best'] for row in entries]
        figure, axis = plt.subplots(figsize=(7.0, 4.2))
        if table.kind == 'star_distance':
            x = np.array([row['measured'] for row in entries]) / 3600.0
            axis.errorbar(x, residual, yerr=[row['sigma'] for row in entries], fmt='o', color='tab:red',
                          label='measured - model')
            line = np.polyfit(x, residual, 1)
            grid = np.linspace(0.0, x.max() * 1.05, 50)
            axis.plot(grid, np.polyval(line, grid), color='tab:red', lw=0.8,
                      label=f'line: {line[0]:+.2f}"/deg ({line[0] / 3600.0 * 1e6:+.0f} ppm)')
            if after[0] is not None:
                axis.plot(x, after, 's', color='tab:blue', label=f'after {result.best_name}')
            axis.set_xlabel('distance between the stars [deg]')
            axis.set_ylabel('measured - predicted distance ["]')
            axis.set_title(f'{table.name}: deviation against distance (Fig. 6.11)')
        else:
            index = np.arange(len(entries))
            axis.bar(index - 0.2, residual, 0.4, color='tab:red', label='measured - model')
            if after[0] is not None:
                axis.bar(index + 0.2, after, 0.4, color='tab:blue', label=f'after {result.best_name}')
            axis.set_xticks(index, [f'{row["label"]} {row["observable"].split(".")[-1]}' for row in entries],
                            rotation=60, fontsize=7)
            axis.set_ylabel('residual [table units]')
            axis.set_title(f'{table.name} ({table.kind})')
        axis.axhline(0.0, color='grey', lw=0.5)
        axis.legend(fontsize=8)
        figure.tight_layout()
        name = f'{table.name}.png'
        figure.savefig(directory / name, dpi=110)
        plt.close(figure)
        images.append(name)
    from io import StringIO

    text = StringIO()
    print_set_comparison(document, text)
    page = ['<!doctype html><html><head><meta charset="utf-8"><title>sofia compare: measurement set</title></head><body>',
            f'<h1>{html.escape(document["title"] or document["measurement_set"])}</h1>',
            f'<p>verdict: <b>{html.escape(document["verdict"]["headline"])}</b>: '
            f'{html.escape(document["verdict"]["text"])}</p>']
    page += [f'<p><img src="{name}" alt="{name}"></p>' for name in images]
    page += [f'<pre>{html.escape(text.getvalue())}</pre>', '</body></html>']
    (directory / 'index.html').write_text('\n'.join(page) + '\n')
    (directory / 'compare.json').write_text(json.dumps(document, indent=2) + '\n')
    return directory / 'index.html'


def run_set_compare(args: argparse.Namespace, out: TextIO, model: EffectConfig) -> int:
    """The measurement-set branch of `sofia compare` (dispatched from compare.cli on a .yaml/.yml path).

    Args:
        args: the parsed `sofia compare` arguments (bag: the set's path, json, report).
        out: where the printed table goes.
        model: the model compared.

    Returns:
        The exit code, 0.
    """
    from sofia_ros.measurements.compare import compare_measurement_set
    from sofia_ros.measurements.validate import load_measurement_set

    measurement_set = load_measurement_set(args.bag)
    result = compare_measurement_set(measurement_set, model)
    document = json_ready(result.document)
    print_set_comparison(document, out)
    # The report first, as for a bag: a report the disk cannot hold leaves no JSON behind either.
    if args.report:
        print(f'report: {write_set_report(result, document, args.report)}', file=out)
    if args.json:
        write_text_atomically(args.json, json.dumps(document, indent=2) + '\n')
    return 0
