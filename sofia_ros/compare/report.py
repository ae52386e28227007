"""The `sofia compare --report DIR` page: where the model fails, at a glance (PNG plots + HTML).

The verdict, every observable against its floor, the structure found (with a plot of the
strongest findings) and the inconsistent terms; residuals against the frame variables per
camera, before and after the best candidate; residual vectors in each detector's pixel plane; the ledger of
this run and of every earlier run written to the same directory (ledger.json), so adding an
effect and comparing again shows the error falling.
"""

from __future__ import annotations

import html
import json
import shutil
import tempfile
from collections.abc import Iterable, Sequence
from os import PathLike
from pathlib import Path
from typing import TYPE_CHECKING, Any

import matplotlib

matplotlib.use('Agg')
import matplotlib.pyplot as plt  # noqa: E402  (the backend must be chosen first)
import numpy as np  # noqa: E402

from sofia_ros.analysis.centroid_drift import line_and_sinusoid_px  # noqa: E402
from sofia_ros.compare.diagnostics import FRAME_VARIABLES, distinct_findings, row_variables  # noqa: E402
from sofia_ros.effects.empirical import DETECTOR_FIELD  # noqa: E402
from sofia_ros.compare.star_hop import hold_rows  # noqa: E402
from sofia_ros.errors import ConfigError  # noqa: E402
from sofia_ros.input_files import read_text_capped  # noqa: E402
from sofia_ros.output_files import output_error  # noqa: E402

if TYPE_CHECKING:
    from sofia_ros.compare.run import CompareResult

__all__ = ['html_table', 'read_ledger', 'write_report']

_LEDGER = 'ledger.json'
#: The largest ledger.json read (a run is about 300 bytes).
_MAX_LEDGER_BYTES = 16 * 1024 * 1024
_GRID = 8


def _binned_means(values, residual, bins=20):
    edges = np.linspace(values.min(), values.max(), bins + 1)
    index = np.clip(np.digitize(values, edges) - 1, 0, bins - 1)
    counts = np.bincount(index, minlength=bins)
    sums = np.bincount(index, residual, minlength=bins)
    filled = counts > 0
    return ((edges[:-1] + edges[1:]) / 2.0)[filled], sums[filled] / counts[filled]


def _residual_plot(result, fits, path):
    observations = result.observations
    centroids = observations.centroids
    predictor_variables = [row_variables(observations, fit, result.predictor) for _, fit in fits]
    cameras = centroids.cameras
    figure, axes = plt.subplots(len(cameras), len(FRAME_VARIABLES), figsize=(3.2 * len(FRAME_VARIABLES), 2.4 * len(cameras)),
                                squeeze=False, sharey='row')
    for row, camera in enumerate(cameras):
        rows = centroids.camera_index == row
        for column, key in enumerate(FRAME_VARIABLES):
            axis = axes[row, column]
            for (name, fit), variables, colour in zip(fits, predictor_variables, ('tab:red', 'tab:blue')):
                # Every row is drawn: when one camera fails, all its rows are "outliers".
                keep = rows
                if np.count_nonzero(keep) < 2:
                    continue
                values = variables[key][keep]
                for component, style in ((0, '-'), (1, '--')):
                    residual = fit.residual_arcsec[keep, component]
                    axis.plot(values, residual, ',', color=colour, alpha=0.25)
                    if np.ptp(values) > 0:
                        centres, means = _binned_means(values, residual)
                        axis.plot(centres, means, style, color=colour, lw=1.2,
                                  label=f'{name} {"XY"[component]}' if row == 0 and column == 0 else None)
            axis.axhline(0.0, color='k', lw=0.5)
            if row == len(cameras) - 1:
                axis.set_xlabel(key)
            if column == 0:
                axis.set_ylabel(f'{camera.upper()} residual ["]')
    if axes[0, 0].get_legend_handles_labels()[0]:  # no labelled line where the first variable does not vary
        axes[0, 0].legend(fontsize=7, loc='upper left')
    figure.suptitle('Residuals (measured - predicted, pixel axes) against the scanned variables; lines: bin means')
    figure.tight_layout()
    figure.savefig(path, dpi=90)
    plt.close(figure)


def _vector_plot(result, fits, path):
    centroids = result.observations.centroids
    cameras = centroids.cameras
    figure, axes = plt.subplots(len(fits), len(cameras), figsize=(3.6 * len(cameras), 3.4 * len(fits)), squeeze=False)
    for row, (name, fit) in enumerate(fits):
        for column, camera in enumerate(cameras):
            axis = axes[row, column]
            # Every row, outliers included: the camera that fails worst is the one to see.
            keep = centroids.camera_index == column
            pixels = centroids.measured_px[keep]
            residual = fit.residual_arcsec[keep]
            if len(pixels) == 0:
                continue
            edges_x = np.linspace(pixels[:, 0].min(), pixels[:, 0].max() + 1e-9, _GRID + 1)
            edges_y = np.linspace(pixels[:, 1].min(), pixels[:, 1].max() + 1e-9, _GRID + 1)
            cell = (np.clip(np.digitize(pixels[:, 0], edges_x) - 1, 0, _GRID - 1) * _GRID
                    + np.clip(np.digitize(pixels[:, 1], edges_y) - 1, 0, _GRID - 1))
            counts = np.bincount(cell, minlength=_GRID * _GRID)
            filled = counts >= 3
            mean_px = np.stack([np.bincount(cell, pixels[:, k], minlength=_GRID**2) for k in (0, 1)], axis=1)
            mean_res = np.stack([np.bincount(cell, residual[:, k], minlength=_GRID**2) for k in (0, 1)], axis=1)
            mean_px = mean_px[filled] / counts[filled, None]
            mean_res = mean_res[filled] / counts[filled, None]
            axis.quiver(mean_px[:, 0], mean_px[:, 1], mean_res[:, 0], mean_res[:, 1], angles='xy',
                        scale_units='inches', scale=1.0)
            axis.set_title(f'{camera.upper()}: {name}', fontsize=8)
            axis.set_xlabel('X [px]')
            axis.set_ylabel('Y [px]')
            axis.set_aspect('equal', adjustable='datalim')
    figure.suptitle('Mean residual vectors in each detector plane (1 inch = 1")')
    figure.tight_layout()
    figure.savefig(path, dpi=90)
    plt.close(figure)


def _ledger_plot(runs, path):
    figure, axis = plt.subplots(figsize=(6.4, 3.2))
    totals = [run['residual_rms_arcsec']['total'] for run in runs]
    floors = [run['noise_floor_arcsec'] for run in runs]
    labels = [f'{index + 1}: {run["last_term"]}' for index, run in enumerate(runs)]
    axis.plot(range(len(runs)), totals, 'o-', label='residual RMS')
    axis.plot(range(len(runs)), floors, 'k--', label='noise floor')
    axis.set_xticks(range(len(runs)), labels, rotation=20, fontsize=7, ha='right')
    axis.set_ylabel('RMS per axis ["]')
    axis.set_yscale('log')
    axis.legend(fontsize=8)
    axis.set_title('Ledger across runs written to this report directory')
    figure.tight_layout()
    figure.savefig(path, dpi=90)
    plt.close(figure)


def _star_hop_plot(analysis, path):
    """Fig. 6.11 (deviation against distance: drift-corrected and short moves, with their lines) and Fig. 6.4."""
    figure, axes = plt.subplots(1, 3, figsize=(13.0, 3.6))
    moves = analysis['moves']
    span = np.linspace(0.0, max(max(move['catalogue_arcsec'] for move in moves) / 3600.0, 1.0), 2)
    for label, key, fit, style in (('drift-corrected moves', 'deviation_arcsec', analysis['deviation_fit'], 'o-'),
                                   ('short moves', 'short_move_deviation_arcsec', analysis['short_move_fit'], 's--')):
        shown = [move for move in moves if move[key] is not None]
        distance_deg = np.array([move['catalogue_arcsec'] for move in shown]) / 3600.0
        points = axes[0].plot(distance_deg, [move[key] for move in shown], style[0],
                              mfc='none' if style[0] == 's' else None, label=label)[0]
        if fit:
            line_label = (f'{fit["slope_arcsec_per_deg"]:+.2f} +- {fit["slope_sigma"]:.2f}"/deg '
                          f'({fit["scale_error_ppm"]:+.0f} ppm)')
            axes[0].plot(span, fit['intercept_arcsec'] + fit['slope_arcsec_per_deg'] * span, style[1:],
                         color=points.get_color(), label=line_label)
    axes[0].axhline(0.0, color='k', lw=0.5)
    axes[0].set_xlabel('catalogue distance [deg]')
    axes[0].set_ylabel('measured - catalogue ["]')
    axes[0].set_title('Fig. 6.11: deviation against distance', fontsize=9)
    axes[0].legend(fontsize=7)
    flexure = analysis['imager_flexure']
    for axis, camera in zip(axes[1:], ('fpi', 'ffi')):
        if not flexure:
            axis.set_visible(False)
            continue
        elevation = [point['elevation_deg'] for point in flexure['points']]
        for component, label in ((0, 'dEL'), (1, 'dXEL')):
            axis.plot(elevation, [point[camera][component] for point in flexure['points']], 'o', label=f'{label}')
            if camera == 'ffi':
                order = np.argsort(elevation)
                axis.plot(np.array(elevation)[order],
                          np.array([point['ffi_fem'][component] for point in flexure['points']])[order], '--',
                          label=f'{label} FEM')
        axis.axhline(0.0, color='k', lw=0.5)
        axis.set_xlabel('elevation [deg]')
        axis.set_ylabel('against HIPO ["]')
        axis.set_title(f'Fig. 6.4: {camera.upper()} boresight against HIPO', fontsize=9)
        axis.legend(fontsize=7)
    figure.tight_layout()
    figure.savefig(path, dpi=90)
    plt.close(figure)


def _centroid_drift_plot(holds, centroids, path):
    """6.3's residual drift: each hold's FPI centroid (column, row) less the fitted offset, with the fitted curve."""
    columns = min(len(holds), 4)
    rows_of_panels = -(-len(holds) // columns)
    figure, axes = plt.subplots(rows_of_panels, columns, figsize=(3.4 * columns, 2.6 * rows_of_panels), squeeze=False)
    for axis, hold in zip(axes.ravel(), holds):
        rows = hold_rows(centroids, 'fpi', hold['hip'], hold)
        elapsed = centroids.stamp_s[rows] - hold['reference_time_s']
        smooth = np.linspace(elapsed.min(), elapsed.max(), 200)
        for index, (axis_name, colour) in enumerate((('column', 'tab:blue'), ('row', 'tab:orange'))):
            fit = hold[axis_name]
            sine = fit.get('sinusoid') or {'amplitude_px': 0.0, 'period_s': 1.0, 'phase_deg': 0.0}
            curve = line_and_sinusoid_px(smooth, 0.0, fit['drift_px_per_min'] / 60.0, sine['amplitude_px'],
                                         sine['period_s'], np.deg2rad(sine['phase_deg']))
            axis.plot(elapsed, centroids.measured_px[rows, index] - fit['offset_px'], '.', color=colour, ms=3)
            label = f'{axis_name} {fit["drift_px_per_min"]:+.1f} px/min' + (' + sinusoid' if fit.get('sinusoid') else '')
            axis.plot(smooth, curve, '-', color=colour, label=label)
        axis.set_title(f'{hold["star"]}, hold at {hold["hold_start_s"]:.0f} s', fontsize=8)
        axis.set_xlabel('time from hold middle [s]', fontsize=7)
        axis.set_ylabel('FPI centroid - offset [px]', fontsize=7)
        axis.legend(fontsize=6)
    for axis in axes.ravel()[len(holds):]:
        axis.set_visible(False)
    figure.suptitle('6.3: residual FPI centroid drift per hold (column linear, row linear + sinusoid where the BIC '
                    'keeps it)', fontsize=9)
    figure.tight_layout()
    figure.savefig(path, dpi=90)
    plt.close(figure)


def _signature_plot(result, document, path):
    """The strongest findings: each camera finding over its rows (bin means and the fitted shape), gyro shapes."""
    centroids = result.observations.centroids
    variables = row_variables(result.observations, result.final_fit, result.predictor)
    findings = distinct_findings([*document['signature']['trends'], *document['signature']['periods']])[:6]
    figure, axes = plt.subplots(2, 3, figsize=(12, 6.4), squeeze=False)
    for axis, finding in zip(axes.ravel(), findings):
        observable = finding['observable']
        source, component = observable.split('.')
        title = f'{observable}: {finding["significance_sigma"]:.1f} sigma'
        if source in centroids.cameras:
            rows = centroids.camera_index == centroids.cameras.index(source)
            residual = result.final_fit.residual_arcsec[rows, 'xy'.index(component)]
            if 'period_s' in finding:
                phase = np.mod(variables['time'][rows], finding['period_s']) / finding['period_s']
                axis.plot(phase, residual, ',', color='tab:red', alpha=0.3)
                centres, means = _binned_means(phase, residual)
                axis.plot(centres, means, 'o-', color='k', ms=3)
                axis.set_xlabel(f'phase of {finding["period_s"]:.4g} s')
            elif finding['variable'] == DETECTOR_FIELD:
                # The 99th percentile: one outlier must not wash the map out.
                limit = float(np.percentile(np.abs(residual), 99.0)) or 1.0
                points = axis.scatter(variables['detector_x'][rows], variables['detector_y'][rows], c=residual, s=2,
                                      cmap='coolwarm', vmin=-limit, vmax=limit)
                figure.colorbar(points, ax=axis, label='residual ["]')
                axis.set_xlabel('detector x [px]')
                axis.set_ylabel('detector y [px]')
            else:
                values = variables[finding['variable']][rows]
                axis.plot(values, residual, ',', color='tab:red', alpha=0.3)
                if np.ptp(values) > 0:
                    centres, means = _binned_means(values, residual)
                    axis.plot(centres, means, 'o', color='k', ms=3, label='bin means')
                if finding['variable'] != 'star':
                    shape = finding['shape']
                    axis.plot(shape['centres'], shape['values_arcsec'], '-', color='tab:blue',
                              label='fitted shape (P0-P3)')
                axis.set_xlabel(finding['variable'])
        else:
            if 'period_s' in finding:
                axis.text(0.5, 0.5, f'period {finding["period_s"]:.4g} s\namplitude {finding["amplitude_arcsec"]:.3f}"',
                          ha='center', va='center', transform=axis.transAxes)
            else:
                shape = finding['shape']
                axis.plot(shape['centres'], shape['values_arcsec'], '-', color='tab:blue')
                axis.set_xlabel(finding['variable'])
            title += ' (anchor walk, studentized)'
        if finding.get('variable') != DETECTOR_FIELD:
            axis.axhline(0.0, color='k', lw=0.5)
            axis.set_ylabel('residual ["]')
        axis.set_title(title, fontsize=9)
    for axis in axes.ravel()[len(findings):]:
        axis.set_visible(False)
    figure.suptitle('Structure left in the residual, strongest first (every row drawn; none dropped)')
    figure.tight_layout()
    figure.savefig(path, dpi=90)
    plt.close(figure)


def html_table(headers: Sequence[object], rows: Iterable[Sequence[object]]) -> str:
    """An HTML table of ``rows`` under ``headers``, every cell escaped.

    Args:
        headers: the column headings, each shown as ``str``.
        rows: the rows, each a sequence of cells shown as ``str``.

    Returns:
        The ``<table>`` element.
    """
    head = ''.join(f'<th>{html.escape(str(h))}</th>' for h in headers)
    body = ''.join('<tr>' + ''.join(f'<td>{html.escape(str(c))}</td>' for c in row) + '</tr>' for row in rows)
    return f'<table><tr>{head}</tr>{body}</table>'


def _page(document, runs):
    cameras = [c for c in ('hipo', 'fpi', 'ffi', 'wfi') if c in document['residual_rms_arcsec']]
    drift_plot = bool(document.get('star_hop', {}).get('centroid_drift'))
    ledger_rows = [[row['term'], *(f'{row["residual_rms_arcsec"].get(k, float("nan")):.3f}' for k in ['total', *cameras])]
                   for row in document['ledger']]
    candidate_rows = [[c['effect'], f'{c["delta_bic"]:.1f}', f'{c["rms_after_arcsec"]:.3f}',
                       ', '.join(f'{k} = {v:.4g} +- {c["sigma"][k] if c["sigma"][k] is not None else float("inf"):.2g} '
                                 f'{c["units"][k]}' for k, v in c['params'].items()),
                       'refit' if c['refined'] else 'linear']
                      for c in document['candidates'] if c['detectable']]
    term_rows = [[t['effect'], t['param'], f'{t["value"]:.4f}', 'unconstrained' if t['sigma'] is None else f'{t["sigma"]:.4f}',
                  t['unit']] for t in document['terms']]
    run_rows = [[index + 1, run['model'], run['last_term'], f'{run["residual_rms_arcsec"]["total"]:.3f}',
                 f'{run["noise_floor_arcsec"]:.3f}', run['top_candidate']] for index, run in enumerate(runs)]
    competing = ''.join(
        f'<p>competing: {html.escape(" or ".join(entry["effects"]))} (delta-BIC '
        f'{html.escape(", ".join(f"{name} {value:.0f}" for name, value in entry["delta_bic"].items()))}; with each: '
        f'{html.escape(", ".join(f"{name} {status or chr(45)}" for name, status in entry["verdict_with_each"].items()))}'
        f'{"; they differ most on " + html.escape(", ".join(entry["separable_by"])) if entry["separable_by"] else ""})</p>'
        for entry in document.get('competing', []))
    degenerate = ''.join(f'<li>{html.escape(a)} and {html.escape(b)} cannot be told apart by this campaign</li>'
                         for a, b in document['degenerate'])
    verdict = document['verdict']
    observable_rows = [[name, entry['kind'], f'{entry["rms_arcsec"]:.3f}', f'{entry["floor_arcsec"]:.3f}',
                        f'{entry["ratio"]:.2f}', 'yes' if entry['explained'] else 'NO', ', '.join(entry['structure'])]
                       for name, entry in verdict['observables'].items()]
    finding_rows = [[f['observable'], f'period {f["period_s"]:.4g} s' if 'period_s' in f else f['variable'],
                     ', '.join(f.get('equivalent_variables', [])), f'{f["amplitude_arcsec"]:.3f}',
                     f'{f["significance_sigma"]:.1f}']
                    for f in sorted([*document['signature']['trends'], *document['signature']['periods']],
                                    key=lambda f: -f['significance_sigma'])]
    consistency_rows = [[c['param'], c['split'], f'{c["values"][0]:.4g} +- {c["sigmas"][0]:.2g}',
                         f'{c["values"][1]:.4g} +- {c["sigmas"][1]:.2g}', f'{c["significance_sigma"]:.1f}']
                        for c in document['consistency']]
    return f'''<!DOCTYPE html>
<html><head><meta charset="utf-8"><title>sofia compare: {html.escape(document["bag"])}</title>
<style>body{{font-family:sans-serif;margin:2em}}table{{border-collapse:collapse;margin:1em 0}}
td,th{{border:1px solid #ccc;padding:3px 8px;font-size:13px}}</style></head><body>
<h1>sofia compare</h1>
<p>Bag <code>{html.escape(document["bag"])}</code>, model <code>{html.escape(document["model"])}</code>.
Noise floor {document["noise_floor_arcsec"]:.3f}" per axis; residual RMS {document["residual_rms_arcsec"]["total"]:.3f}";
{document["outliers"]} outliers flagged.</p>
<h2>Verdict: {html.escape(verdict["headline"])}</h2><p>{html.escape(verdict["text"])}</p>{competing}
<h2>Every observable against its own floor</h2>
{html_table(["observable", "kind", "RMS [arcsec]", "floor [arcsec]", "ratio", "explained", "structure"], observable_rows)}
<h2>Structure in the residual</h2><p>Family-wise significance over {document["signature"]["tests_run"]} tests
(structure from {document["signature"]["detection_sigma"]:g} sigma; listed from 3).</p>
{html_table(["observable", "variable or period", "same as (here)", "amplitude [arcsec]", "sigma"], finding_rows)}
{'<img src="signature.png" alt="strongest findings">' if finding_rows else ''}
<h2>Fitted terms that change between halves of the data</h2>
{html_table(["term", "split", "one half", "other half", "sigma"], consistency_rows) if consistency_rows else '<p>none</p>'}
<h2>Where the model fails</h2><img src="residuals.png" alt="residuals against variables">
<img src="vectors.png" alt="residual vectors in the detector planes">
{'<h2>Star hop (6.2, 6.3)</h2><img src="star_hop.png" alt="star hop">' if 'star_hop' in document else ''}
{'<img src="star_hop_drift.png" alt="FPI centroid drift per hold">' if drift_plot else ''}
<h2>Ledger of this run</h2>{html_table(["step", "total", *[c.upper() for c in cameras]], ledger_rows)}
<h2>Ledger across runs</h2><img src="ledger.png" alt="ledger across runs">
{html_table(["run", "model", "last fitted term", "RMS", "floor", "top candidate"], run_rows)}
<h2>Fitted terms</h2>{html_table(["effect", "parameter", "value", "sigma", "unit"], term_rows)}
<h2>Candidates</h2>{html_table(["effect", "delta-BIC", "RMS after", "parameters", "fit"], candidate_rows)}
<p>Not observable in this campaign: {html.escape(", ".join(document["unobservable"]) or "none")}.</p>
<ul>{degenerate}</ul>
</body></html>
'''


def read_ledger(directory: str | PathLike[str]) -> list[dict[str, Any]]:
    """The runs of the ledger.json in a report directory ([] without one); ConfigError in one line naming the fix
    unless it is a regular file of at most _MAX_LEDGER_BYTES holding a ledger sofia compare wrote. Read before the
    comparison runs (`sofia compare --report`): a link to /dev/full there was read until memory ran out, and a
    ledger of another shape failed only after the comparison, in a traceback.

    Args:
        directory: the report directory.

    Returns:
        The earlier runs, oldest first.

    Raises:
        ConfigError: ledger.json is a device, FIFO, folder or too large, not UTF-8 JSON, or not a list of runs.
    """
    path = Path(directory) / _LEDGER
    if not path.exists() and not path.is_symlink():
        return []
    fix = 'remove it or give another --report directory'
    try:
        runs = json.loads(read_text_capped(path, _MAX_LEDGER_BYTES, 'ledger'))
    except ConfigError as err:
        raise ConfigError(f'{err}; {fix}') from err
    except json.JSONDecodeError as err:
        raise ConfigError(f'{path} is not a ledger written by sofia compare ({err.msg}); {fix}') from err
    if not isinstance(runs, list) or not all(_is_ledger_run(run) for run in runs):
        raise ConfigError(f'{path} is not a ledger written by sofia compare (not a list of runs); {fix}')
    return runs


def _is_ledger_run(run: Any) -> bool:
    """Whether ``run`` has what _ledger_plot draws: a model, a last term, numbers for the RMS total and floor."""
    numbers = (int, float)
    return (isinstance(run, dict) and isinstance(run.get('last_term'), str)
            and isinstance(run.get('residual_rms_arcsec'), dict)
            and isinstance(run['residual_rms_arcsec'].get('total'), numbers)
            and isinstance(run.get('noise_floor_arcsec'), numbers)
            and not isinstance(run['noise_floor_arcsec'], bool))


def write_report(result: CompareResult, document: dict[str, Any], directory: str | PathLike[str]) -> Path:
    """Write index.html and the PNGs into ``directory`` (created if needed), all files or none; OutputError in one
    line (exit 3 for a full disk) naming ``directory`` when the disk refuses them.

    Args:
        result: the comparison (its fits and observations are plotted).
        document: the comparison's JSON document (docs/compare.md), JSON-ready.
        directory: the report directory; its ledger.json, if any, gains this run.

    Returns:
        The path of the written index.html.

    Raises:
        ConfigError: ``directory`` is a file, or its ledger.json is not a ledger.
        OutputError: the disk refuses the files (exit 3 when it is full).
    """
    directory = Path(directory)
    if directory.exists() and not directory.is_dir():
        raise ConfigError(f'--report {directory} is a file; give a directory')
    runs = read_ledger(directory)
    top = next((c['effect'] for c in document['candidates']
                if c['detectable'] and c['delta_bic'] >= document['significant_delta_bic']), 'none')
    runs.append({'model': document['model'], 'last_term': document['ledger'][-1]['term'],
                 'residual_rms_arcsec': document['residual_rms_arcsec'],
                 'noise_floor_arcsec': document['noise_floor_arcsec'], 'top_candidate': top})
    try:
        _write_staged(result, document, runs, directory)
    except OSError as err:
        # Named by the report directory: the staging folder the error is about is gone.
        raise output_error(directory, err) from err
    return directory / 'index.html'


def _write_staged(result, document, runs, directory):
    """Draw every file in a staging folder beside ``directory``, then move them in (the staging folder removed)."""
    fits = [('model', result.final_fit)]
    if result.best_fit is not None:
        fits.append((f'+ {result.best_name}', result.best_fit))
    directory.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix='.sofia_report_', dir=directory.parent) as staging:
        staging = Path(staging)
        _residual_plot(result, fits, staging / 'residuals.png')
        _vector_plot(result, fits, staging / 'vectors.png')
        if document['signature']['trends'] or document['signature']['periods']:
            _signature_plot(result, document, staging / 'signature.png')
        _ledger_plot(runs, staging / 'ledger.png')
        if 'star_hop' in document:
            _star_hop_plot(document['star_hop'], staging / 'star_hop.png')
            if document['star_hop']['centroid_drift']:
                _centroid_drift_plot(document['star_hop']['centroid_drift'], result.observations.centroids,
                                     staging / 'star_hop_drift.png')
        (staging / 'index.html').write_text(_page(document, runs))
        (staging / _LEDGER).write_text(json.dumps(runs, indent=2) + '\n')
        directory.mkdir(exist_ok=True)
        for staged in staging.iterdir():
            shutil.move(str(staged), directory / staged.name)
