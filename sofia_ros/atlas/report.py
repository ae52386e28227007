"""The atlas for a planner: a one-screen text table and an HTML page with PNG plots (matplotlib); for truths
with several effects, the success rates per campaign and k, the controls' rate, the pairs most often confused and
every truth that did not end right."""

from __future__ import annotations

import html
import math
from collections import defaultdict
from dataclasses import dataclass
from pathlib import Path

from sofia_ros.atlas.scoring import SCORES
from sofia_ros.atlas.stats import (CONFIDENCE, TABLE_6_5, confusions, detectable_sizes, detection_curves,
                                   fit_calibration, table_6_5_slice, thesis_sigmas_arcsec, truth_confusions,
                                   truth_misses, truth_rates)
from sofia_ros.compare.report import html_table
from sofia_ros.output_files import atomic_output, write_text_atomically

__all__ = ['AtlasSummary', 'miss_line', 'summarize', 'text_table', 'truth_lines', 'write_html']

#: Lines of the confusion and calibration blocks on the one-screen table (the page has them all).
_SCREEN_LINES = 5


@dataclass(frozen=True)
class AtlasSummary:
    """Every derived table of one atlas."""

    rows: list
    points: list
    detectable: list
    calibration: list
    confused: list
    table_6_5: list
    table_6_5_rows: str
    truth_rates: list = ()
    truth_confused: list = ()
    truth_misses: list = ()


def summarize(rows: list[dict]) -> AtlasSummary:
    """The derived tables (atlas.stats) of the rows."""
    points = detection_curves(rows)
    table, which = table_6_5_slice(rows)
    return AtlasSummary(rows, points, detectable_sizes(points), fit_calibration(rows), confusions(rows), table, which,
                        truth_rates(rows), truth_confusions(rows), truth_misses(rows))


def miss_line(row: dict) -> str:
    """One truth that did not end right: its key, what was hidden, the final model's changes, status and rounds."""
    change = ' '.join([*(f'+{name}' for name in (row['final_added'] or '').split(',') if name),
                       *(f'-{name}' for name in (row['final_removed'] or '').split(',') if name)])
    return (f'{row["score"]}: {row["key"]}: hidden {row["truth_effects"] or "nothing"} -> final '
            f'{change or "the model as given"} ({row["verdict"]}, {row["rounds"]} comparisons)')


def truth_lines(summary: AtlasSummary, screen: bool = True) -> list[str]:
    """The truth block: success per campaign and k with the controls, the pairs most often confused, the misses
    (on a screen the first few of each)."""
    if not summary.truth_rates:
        return []
    limit = _SCREEN_LINES if screen else None
    lines = ['truths: right = exact, or equivalent up to the competitors or equivalent models the output states;',
             '  a control (k=0) is right when it ends explained with nothing added',
             f'  {"campaign":<20} {"k":>2} {"right/runs":>10} {"rate":>5} {"95% interval":>12}  '
             + ' '.join(f'{name:>10}' for name in SCORES)]
    for rate in summary.truth_rates:
        lines.append(f'  {rate.campaign:<20} {rate.k:>2} {f"{rate.successes}/{rate.trials}":>10} '
                     f'{rate.probability:>5.0%} {f"{rate.low:.2f}-{rate.high:.2f}":>12}  '
                     + ' '.join(f'{rate.counts[name]:>10}' for name in SCORES))
    if summary.truth_confused:
        lines.append('  pairs most often confused (hidden -> in the final model instead; times, of them stated as '
                     'competitors):')
        lines += [f'    {c.hidden} -> {c.named} ({c.campaign}): {c.count}x, {c.stated} stated'
                  for c in summary.truth_confused[:limit]]
    if summary.truth_misses:
        lines.append(f'  not right ({len(summary.truth_misses)}):')
        lines += [f'    {miss_line(row)}' for row in summary.truth_misses[:limit]]
    return lines


def _size_text(found) -> str:
    if found.bound == '>':
        return f'>{found.size:g}'
    return f'{"<=" if found.bound == "<=" else ""}{found.size:.3g}'


def _detectable_by_key(summary):
    table = defaultdict(dict)
    for found in summary.detectable:
        table[(found.effect, found.campaign)][found.level] = _size_text(found)
    return table


def text_table(summary: AtlasSummary) -> str:
    """One screen: detections per size, the 50/90 % sizes, the worst confusions and sigma calibrations, Table 6.5."""
    failed = sum(row['error'] is not None for row in summary.rows)
    lines = [f'atlas: {len(summary.rows)} rows, {failed} failed']
    if summary.points:
        lines[0] += '; detected = the hidden effect is compare\'s top candidate at delta-BIC >= 6'
        lines.append(f'{"effect":<28} {"campaign":<20} {"50%":>7} {"90%":>7}  detected/runs by size (x default)')
    curves = defaultdict(list)
    for point in summary.points:
        curves[(point.effect, point.campaign)].append(point)
    sizes = _detectable_by_key(summary)
    for key, curve in sorted(curves.items()):
        cells = '  '.join(f'{p.size:g}:{p.detections}/{p.trials}' for p in sorted(curve, key=lambda p: p.size))
        lines.append(f'{key[0]:<28} {key[1]:<20} {sizes[key].get(0.5, "-"):>7} {sizes[key].get(0.9, "-"):>7}  {cells}')
    if summary.confused:
        lines.append('confused (hidden -> named instead, share of runs with it hidden):')
        for item in summary.confused[:_SCREEN_LINES]:
            lines.append(f'  {item.effect} -> {item.other} ({item.kind}, {item.campaign}): {item.count}/{item.trials}')
    worst = sorted((c for c in summary.calibration if math.isfinite(c.pull_std)), key=lambda c: -abs(c.pull_std - 1.0))
    if worst:
        lines.append('sigma calibration (pull = (fitted - true) / sigma; honest sigmas: mean 0, std 1), worst first:')
        for c in worst[:_SCREEN_LINES]:
            lines.append(f'  {c.effect}.{c.param} {c.campaign} x{c.size:g}: bias {c.bias:+.3g}, scatter '
                         f'{c.scatter:.3g}, sigma {c.median_sigma:.3g}, pull {c.pull_mean:+.2f}+-{c.pull_std:.2f} '
                         f'n={c.count}' + (f' ({c.unconstrained} without sigma)' if c.unconstrained else ''))
    if summary.table_6_5:
        lines.append(f'Table 6.5 slice ({summary.table_6_5_rows}): alignment against /truth, RMS over runs ["]')
        lines.append('  variant        n  runs  tilt RMS  predicted  thesis sigma_R   LOS RMS  predicted  thesis sigma_beta')
        for row in summary.table_6_5:
            lines.append(f'  {row.variant:<12} {row.measurements:>3} {row.runs:>5} {row.tilt_rms_arcsec:>9.2f} '
                         f'{row.predicted_tilt_arcsec:>10.2f} {row.thesis_sigma_r_arcsec:>15.2f} '
                         f'{row.los_rms_arcsec:>9.1f} {row.predicted_los_arcsec:>10.1f} '
                         f'{row.thesis_sigma_beta_arcsec:>18.1f}')
    lines += truth_lines(summary)
    return '\n'.join(lines) + '\n'


def _detection_plot(summary, campaign, path):
    import matplotlib

    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    figure, axes = plt.subplots(figsize=(8, 4.5))
    curves = defaultdict(list)
    for point in summary.points:
        if point.campaign == campaign:
            curves[point.effect].append(point)
    for effect, curve in sorted(curves.items()):
        curve = sorted(curve, key=lambda p: p.size)
        sizes = [p.size for p in curve]
        probability = [p.probability for p in curve]
        errors = [[p.probability - p.low for p in curve], [p.high - p.probability for p in curve]]
        axes.errorbar(sizes, probability, yerr=errors, marker='o', capsize=3, label=effect)
    axes.axhline(0.5, color='grey', linestyle=':')
    axes.axhline(0.9, color='grey', linestyle='--')
    axes.set_xlabel('size (x the thesis default)')
    axes.set_ylabel(f'detection probability ({CONFIDENCE:.0%} Clopper-Pearson)')
    axes.set_ylim(-0.05, 1.05)
    axes.set_title(f'{campaign}: the hidden effect is the top candidate at delta-BIC >= 6')
    axes.legend(fontsize='small')
    figure.tight_layout()
    with atomic_output(path, 'wb') as stream:  # a killed atlas leaves no half-written PNG
        figure.savefig(stream, format='png', dpi=90)
    plt.close(figure)


def _table_6_5_plot(summary, path):
    import matplotlib

    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    figure, (tilt, los) = plt.subplots(1, 2, figsize=(9, 4))
    n = [row.measurements for row in summary.table_6_5]
    for axes, measured, predicted, printed, name in (
            (tilt, 'tilt_rms_arcsec', 'predicted_tilt_arcsec', 0, 'tilt (about EL, XEL) ["]'),
            (los, 'los_rms_arcsec', 'predicted_los_arcsec', 1, 'about LOS ["]')):
        axes.plot(n, [getattr(row, measured) for row in summary.table_6_5], 'o', label='atlas: RMS against /truth')
        axes.plot(n, [getattr(row, predicted) for row in summary.table_6_5], 's', label='calibration node: predicted')
        curve_n = list(range(1, max(18, *n) + 1))
        axes.plot(curve_n, [thesis_sigmas_arcsec(count)[printed] for count in curve_n], '-', color='green',
                  label='eqs. 3.32/3.34/3.37, sigma_c 0.327"')
        scale = 1.0 if printed == 0 else 60.0
        axes.plot(list(TABLE_6_5), [value[printed] * scale for value in TABLE_6_5.values()], 'k+', markersize=12,
                  label='Table 6.5 as printed')
        axes.set_xscale('log')
        axes.set_yscale('log')
        axes.set_xlabel('measurements per axis n')
        axes.set_ylabel(name)
        axes.legend(fontsize='x-small')
    figure.suptitle(f'Table 6.5: alignment accuracy against the number of measurements ({summary.table_6_5_rows})')
    figure.tight_layout()
    with atomic_output(path, 'wb') as stream:  # a killed atlas leaves no half-written PNG
        figure.savefig(stream, format='png', dpi=90)
    plt.close(figure)


def _single_effect_section(detect_rows, confused_rows, calibration_rows) -> str:
    """The page's tables of the effects axis: detection and detectable sizes, confused pairs, sigma calibration."""
    return (f'<h2>Detection probability ({CONFIDENCE:.0%} Clopper-Pearson) and detectable sizes</h2>'
            + html_table(['effect', 'campaign', 'size', 'detected', 'P', 'interval', '50 % size', '90 % size'],
                         detect_rows)
            + '<h2>Confused pairs</h2>'
            + (html_table(['hidden', 'named', 'how', 'campaign', 'share'], confused_rows) if confused_rows
               else '<p>none</p>')
            + '<h2>Fit bias and scatter against the reported sigma</h2>'
            + (html_table(['effect', 'param', 'campaign', 'size', 'runs', 'true', 'bias', 'scatter', 'median sigma',
                           'pull mean', 'pull std'], calibration_rows) if calibration_rows
               else '<p>no fitted values</p>'))


def _truth_section(summary: AtlasSummary) -> str:
    """The page's truth tables: rates per campaign and k, the confused pairs, every truth not ended right."""
    if not summary.truth_rates:
        return ''
    rates = [[r.campaign, r.k if r.k else '0 (controls)', f'{r.successes}/{r.trials}', f'{r.probability:.2f}',
              f'{r.low:.2f}-{r.high:.2f}', *(r.counts[name] for name in SCORES)] for r in summary.truth_rates]
    confused = [[c.hidden, c.named, c.campaign, c.count, c.stated] for c in summary.truth_confused]
    misses = [[row['key'], row['score'], row['truth_effects'] or 'nothing', row['final_added'] or '-',
               row['final_removed'] or '-', row['verdict'], row['rounds']] for row in summary.truth_misses]
    return ('<h2>Truths with several effects: success per campaign and k</h2>'
            '<p>right = exact, or equivalent up to the competing sets and equivalent models the output states; a '
            f'control (k = 0) is right when it ends explained with nothing added; {CONFIDENCE:.0%} Clopper-Pearson '
            'intervals.</p>'
            + html_table(['campaign', 'k', 'right/runs', 'rate', 'interval', *SCORES], rates)
            + '<h2>Pairs most often confused (hidden, in the final model instead)</h2>'
            + (html_table(['hidden', 'named instead', 'campaign', 'times', 'stated as competitors'], confused)
               if confused else '<p>none</p>')
            + '<h2>Truths not ended right</h2>'
            + (html_table(['key', 'score', 'hidden', 'added', 'removed', 'status', 'comparisons'], misses)
               if misses else '<p>none</p>'))


def write_html(summary: AtlasSummary, directory, title: str) -> Path:
    """index.html with a detection plot per campaign, the tables, and the Table 6.5 slice; its path."""
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    campaigns = sorted({point.campaign for point in summary.points})
    sections = []
    for index, campaign in enumerate(campaigns):
        name = f'detection-{index}.png'
        _detection_plot(summary, campaign, directory / name)
        sections.append(f'<h2>{html.escape(campaign)}</h2><img src="{name}" alt="detection against size">')
    sizes = _detectable_by_key(summary)
    detect_rows = [[p.effect, p.campaign, f'{p.size:g}', f'{p.detections}/{p.trials}', f'{p.probability:.2f}',
                    f'{p.low:.2f}-{p.high:.2f}', sizes[(p.effect, p.campaign)].get(0.5, '-'),
                    sizes[(p.effect, p.campaign)].get(0.9, '-')] for p in summary.points]
    calibration_rows = [[c.effect, c.param, c.campaign, f'{c.size:g}', c.count, f'{c.true_value:.4g}', f'{c.bias:+.3g}',
                         f'{c.scatter:.3g}', f'{c.median_sigma:.3g}', f'{c.pull_mean:+.2f}', f'{c.pull_std:.2f}']
                        for c in summary.calibration]
    confused_rows = [[c.effect, c.other, c.kind, c.campaign, f'{c.count}/{c.trials}'] for c in summary.confused]
    table_6_5 = ''
    if summary.table_6_5:
        _table_6_5_plot(summary, directory / 'table-6-5.png')
        table_6_5 = ('<h2>Table 6.5: alignment accuracy against the number of measurements</h2>'
                     f'<p>{html.escape(summary.table_6_5_rows)}; Table 6.5 prints sigma_R 5.3" / 1.2" and '
                     "sigma_beta 5.5' / 1.3' for n = 1 / 18 at sigma_c = 0.327\".</p>"
                     + html_table(['variant', 'n', 'runs', 'tilt RMS ["]', 'predicted', 'thesis sigma_R',
                                   'LOS RMS ["]', 'predicted', 'thesis sigma_beta'],
                                  [[r.variant, r.measurements, r.runs, f'{r.tilt_rms_arcsec:.2f}',
                                    f'{r.predicted_tilt_arcsec:.2f}', f'{r.thesis_sigma_r_arcsec:.2f}',
                                    f'{r.los_rms_arcsec:.1f}', f'{r.predicted_los_arcsec:.1f}',
                                    f'{r.thesis_sigma_beta_arcsec:.1f}'] for r in summary.table_6_5])
                     + '<img src="table-6-5.png" alt="Table 6.5 slice">')
    page = f"""<!doctype html>
<html><head><meta charset="utf-8"><title>sofia atlas: {html.escape(title)}</title>
<style>body{{font-family:sans-serif;max-width:70em}}table{{border-collapse:collapse}}td,th{{border:1px solid #ccc;padding:2px 6px}}</style>
</head><body>
<h1>sofia atlas: {html.escape(title)}</h1>
<pre>{html.escape(text_table(summary))}</pre>
{''.join(sections)}
{_single_effect_section(detect_rows, confused_rows, calibration_rows) if summary.points else ''}
{table_6_5}
{_truth_section(summary)}
</body></html>
"""
    path = directory / 'index.html'
    write_text_atomically(path, page)
    return path
