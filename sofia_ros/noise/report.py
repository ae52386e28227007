"""`sofia noise --report DIR`: an HTML page with the plots of thesis 5.2 for one record.

rates.png (Fig. 5.7), angle.png (Figs. 5.8-5.9), psd.png (Figs. 5.10-5.12, lines marked and named),
spectrogram.png (Fig. 5.5), allan.png (Figs. 5.13-5.16: 4.25 error bars, the five-term fit and the
noise model), allan_residual.png (ln root AV against both). Figures are drawn on matplotlib's Agg
canvas directly (no pyplot state). The page is built in a hidden sibling directory and renamed
into place, so a failure leaves nothing behind.
"""

from __future__ import annotations

import html
import shutil
import tempfile
from os import PathLike
from pathlib import Path

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from sofia_ros.analysis.spectra import rate_spectrogram
from sofia_ros.errors import ConfigError
from sofia_ros.frames import AXES
from sofia_ros.noise.fit import noise_adev
from sofia_ros.noise.predict import predicted_noise
from sofia_ros.noise.run import NoiseAnalysis, integrated_angle_arcsec

__all__ = ['PLOTS', 'check_report_dir', 'write_report']

#: File name and caption of every plot on the page.
PLOTS = (
    ('rates.png', 'Angular rates about their mean (Fig. 5.7): block mean and min/max envelope'),
    ('angle.png', 'Mean value subtracted, integrated rates (Figs. 5.8-5.9)'),
    ('psd.png', 'Rate PSD, Welch as in 5.2.5, with the detected lines and the noise model (Figs. 5.10-5.12)'),
    ('spectrogram.png', 'Spectrogram of the rates, PSD in dB (Fig. 5.5)'),
    ('allan.png', 'Root Allan variance with 1-sigma bars (4.25), five-term fit (4.24) and noise model '
                  '(Figs. 5.13-5.16)'),
    ('allan_residual.png', 'ln(measured / predicted root AV) with the 4.25 band'),
)
#: Specification of Table 5.8 (also Table 5.1): ARW 0.018"/sqrt(s), bias stability 0.003"/s.
_SPEC_ARW_ARCSEC_PER_SQRT_S = 0.018
_SPEC_BIAS_STABILITY_ARCSEC_PER_S = 0.003
_PLOT_POINTS = 2000
_SPECTROGRAM_COLUMNS = 600
_COLOURS = {'el': 'tab:blue', 'xel': 'tab:orange', 'los': 'tab:green'}


def check_report_dir(report_dir: str | PathLike[str]) -> Path:
    """Refuse a --report target that exists with content or whose parent is missing (before any work).

    Args:
        report_dir: the --report directory.

    Returns:
        It as a Path; a link to an empty directory as that directory (the report takes its place).

    Raises:
        ConfigError: it exists with content (or is no directory), or its parent is missing.
    """
    target = Path(report_dir)
    if target.is_symlink() and target.is_dir():
        # Renaming the finished report over the link's target: removing the link itself as a folder failed after the
        # whole analysis ("a part of the path is a file").
        target = target.resolve()
    if target.exists() and not target.is_dir():
        raise ConfigError(f'--report {target} is not a directory (a file or a device); give a new or empty directory')
    if target.exists() and any(target.iterdir()):
        raise ConfigError(f'report directory {target} already exists and is not empty; choose another --report '
                          'or remove it')
    if not target.parent.is_dir():
        raise ConfigError(f'cannot write report {target}: {target.parent} is not a directory; create it first')
    return target


def _save(figure, path):
    FigureCanvasAgg(figure)
    figure.savefig(path, dpi=100)


def _blocks(values, count):
    """values (n x 3) reduced to at most count blocks: (block index start, mean, min, max)."""
    size = max(1, len(values) // count)
    usable = values[:len(values) // size * size].reshape(-1, size, values.shape[1])
    return np.arange(usable.shape[0]) * size, usable.mean(axis=1), usable.min(axis=1), usable.max(axis=1)


def _rates_figure(analysis, path):
    start, mean, low, high = _blocks(analysis.noise_arcsec_per_s, _PLOT_POINTS)
    minutes = start / analysis.sample_rate_hz / 60.0
    figure = Figure(figsize=(10, 7), layout='constrained')
    for index, axis in enumerate(AXES):
        plot = figure.add_subplot(3, 1, index + 1)
        plot.fill_between(minutes, low[:, index], high[:, index], color='0.8', label='min/max')
        plot.plot(minutes, mean[:, index], color=_COLOURS[axis], lw=0.8, label='block mean')
        plot.set_ylabel(f'{axis.upper()} rate ["/s]')
        plot.legend(loc='upper right', fontsize='small')
    plot.set_xlabel('time [min]')
    _save(figure, path)


def _angle_figure(analysis, path):
    angle = integrated_angle_arcsec(analysis.noise_arcsec_per_s, analysis.sample_rate_hz)
    step = max(1, len(angle) // _PLOT_POINTS)
    minutes = np.arange(0, len(angle), step) / analysis.sample_rate_hz / 60.0
    figure = Figure(figsize=(10, 4.5), layout='constrained')
    plot = figure.add_subplot()
    for index, axis in enumerate(AXES):
        plot.plot(minutes, angle[::step, index], color=_COLOURS[axis], label=axis.upper())
    plot.set_xlabel('time [min]')
    plot.set_ylabel('angle ["]')
    plot.legend()
    plot.grid(alpha=0.3)
    _save(figure, path)


def _model_psd(analysis, freq_hz):
    """The noise model with its refitted white level (noise.candidates.fit_base) on any frequencies."""
    _, rest = predicted_noise(analysis.effects, analysis.measured.grid, freq_hz, include_arw=False)
    return rest + 2.0 * analysis.base.white_level[:, np.newaxis]


def _psd_figure(analysis, path):
    document = analysis.document
    freq_hz, psd = analysis.freq_hz[1:], analysis.psd[1:]
    model = _model_psd(analysis, freq_hz)
    figure = Figure(figsize=(10, 10), layout='constrained')
    for index, axis in enumerate(AXES):
        plot = figure.add_subplot(3, 1, index + 1)
        plot.loglog(freq_hz, psd[:, index], color='0.45', lw=0.6, label='measured (Welch)')
        plot.loglog(freq_hz, model[index], color='tab:red', lw=1.0, ls='--', label='noise model')
        plot.axhline(2.0 * _SPEC_ARW_ARCSEC_PER_SQRT_S**2, color='k', ls=':', lw=0.8,
                     label='specified ARW, 2 N^2 (4.14)')
        plot.set_ylim(top=float(psd[:, index].max()) * 300.0)
        for line in document['axes'][axis]['lines']:
            level = float(np.interp(line['freq_hz'], freq_hz, psd[:, index]))
            plot.plot(line['freq_hz'], level * 1.6, marker='v', color=_COLOURS[axis], ms=5)
            name = line['source'] if line['source'] != 'unknown' else f'{line["freq_hz"]:.1f} Hz'
            plot.text(line['freq_hz'], 0.98, name, transform=plot.get_xaxis_transform(), fontsize=6, rotation=90,
                      ha='center', va='top')
        plot.set_ylabel(f'{axis.upper()} PSD [("/s)^2/Hz]')
        plot.legend(loc='lower left', fontsize='small')
        plot.grid(alpha=0.3, which='both')
    plot.set_xlabel('frequency [Hz]')
    _save(figure, path)


def _spectrogram_figure(analysis, path):
    segment = min(2**12, analysis.segment_samples)
    figure = Figure(figsize=(10, 9), layout='constrained')
    for index, axis in enumerate(AXES):
        freq_hz, time_s, power = rate_spectrogram(analysis.noise_arcsec_per_s[:, index], analysis.sample_rate_hz,
                                                  segment_samples=segment)
        group = max(1, time_s.size // _SPECTROGRAM_COLUMNS)
        columns = time_s.size // group
        power = power[:, :columns * group].reshape(power.shape[0], columns, group).mean(axis=2)
        decibel = 10.0 * np.log10(np.maximum(power, np.finfo(float).tiny))
        plot = figure.add_subplot(3, 1, index + 1)
        image = plot.imshow(decibel, origin='lower', aspect='auto', cmap='gray_r',
                            extent=(time_s[0] / 60.0, time_s[columns * group - 1] / 60.0, freq_hz[0], freq_hz[-1]),
                            vmin=np.percentile(decibel, 5), vmax=np.percentile(decibel, 99.9))
        figure.colorbar(image, ax=plot, label='dB re ("/s)^2/Hz')
        plot.set_ylabel(f'{axis.upper()} frequency [Hz]')
    plot.set_xlabel('time [min]')
    _save(figure, path)


def _allan_figure(analysis, path):
    figure = Figure(figsize=(10, 11), layout='constrained')
    for index, (axis, curve, fit) in enumerate(zip(AXES, analysis.curves, analysis.fits)):
        plot = figure.add_subplot(3, 1, index + 1)
        plot.errorbar(curve.tau_s, curve.adev, yerr=curve.adev * curve.sigma_rel, fmt='o', ms=3,
                      color=_COLOURS[axis], ecolor='0.6', label='measured, 1 sigma (4.25)')
        plot.loglog(curve.tau_s, noise_adev(curve.tau_s, **fit.as_arcsec()), color='k', ls='--',
                    label='five-term fit (4.24)')
        plot.loglog(curve.tau_s, np.sqrt(analysis.base.av[index]), color='tab:red', ls=':', lw=1.5,
                    label='noise model, ARW refitted')
        plot.loglog(curve.tau_s, _SPEC_ARW_ARCSEC_PER_SQRT_S / np.sqrt(curve.tau_s), color='0.5', lw=0.8,
                    label='specification: ARW, bias stability')
        plot.axhline(_SPEC_BIAS_STABILITY_ARCSEC_PER_S, color='0.5', lw=0.8)
        stability = analysis.document['axes'][axis]
        plot.plot(stability['bias_stability_tau_s'], stability['bias_stability_arcsec_per_s'], marker='*',
                  color='k', ms=10, ls='none', label='bias stability (minimum)')
        plot.set_ylabel(f'{axis.upper()} root AV ["/s]')
        plot.legend(loc='lower left', fontsize='small')
        plot.grid(alpha=0.3, which='both')
    plot.set_xlabel('averaging time tau [s]')
    _save(figure, path)


def _residual_figure(analysis, path):
    figure = Figure(figsize=(10, 9), layout='constrained')
    for index, (axis, curve, fit) in enumerate(zip(AXES, analysis.curves, analysis.fits)):
        plot = figure.add_subplot(3, 1, index + 1)
        plot.fill_between(curve.tau_s, -curve.sigma_rel, curve.sigma_rel, color='0.85', label='1 sigma (4.25)')
        plot.semilogx(curve.tau_s, np.log(curve.adev) - 0.5 * np.log(analysis.base.av[index]), 'o-', ms=3,
                      color='tab:red', label='against the noise model')
        plot.semilogx(curve.tau_s, np.log(curve.adev / noise_adev(curve.tau_s, **fit.as_arcsec())), 's-', ms=2,
                      color='k', lw=0.6, label='against the five-term fit')
        plot.axhline(0.0, color='k', lw=0.5)
        plot.set_ylabel(f'{axis.upper()} ln ratio')
        plot.legend(loc='upper left', fontsize='small')
        plot.grid(alpha=0.3, which='both')
    plot.set_xlabel('averaging time tau [s]')
    _save(figure, path)


def _table(header, rows):
    head = ''.join(f'<th>{html.escape(str(cell))}</th>' for cell in header)
    body = ''.join('<tr>' + ''.join(f'<td>{html.escape(str(cell))}</td>' for cell in row) + '</tr>' for row in rows)
    return f'<table><tr>{head}</tr>{body}</table>'


def _number(value, digits=4):
    return 'n/a' if value is None or not np.isfinite(value) else f'{value:.{digits}g}'


def _page(document):
    earth = document['earth_rate_deg_per_h']
    earth_rows = [('measurement mean', *(f'{earth["measured"][a]:.4f}' for a in AXES))]
    if earth['misalignment_corrected'] is not None:
        earth_rows.append(('misalignment corrected', *(f'{earth["misalignment_corrected"][a]:.4f}' for a in AXES)))
    earth_rows += [
        (f'theoretical, heading {earth["heading_deg"]:.1f} deg', *(f'{earth["theoretical"][a]:.4f}' for a in AXES)),
        ('deviation', *(f'{earth["deviation"][a]:.4f}' for a in AXES)),
        (f'theoretical, least-squares heading {earth["best_fit_heading_deg"]:.2f} deg',
         *(f'{earth["theoretical_at_best_fit_heading"][a]:.4f}' for a in AXES)),
        ('deviation', *(f'{earth["deviation_at_best_fit_heading"][a]:.4f}' for a in AXES)),
    ]
    noise_rows = [(axis.upper(), f'{v["arw_arcsec_per_sqrt_s"]:.4f} +- {v["arw_sigma"]:.4f}',
                   f'{v["bias_stability_arcsec_per_s"]:.4f}',
                   f'{v["bias_stability_tau_s"]:.0f}' + ('' if v['bias_stability_resolved'] else ' (not resolved)'),
                   f'{v["rrw_arcsec_per_s_sqrt_s"]:.2e} +- {v["rrw_sigma"]:.1e}',
                   f'{v["integrated_angle_max_arcsec"]:.2f}')
                  for axis, v in document['axes'].items()]
    line_rows = [(axis.upper(), f'{line["freq_hz"]:.2f}', f'{line["amplitude_arcsec_per_s"]:.3f}', line['source'])
                 for axis, values in document['axes'].items() for line in values['lines']]
    candidate_rows = [(c['label'], c.get('source', ''), f'{c["delta_bic"]:.1f}',
                       ', '.join(f'{k} = {_number(v)} +- {_number(c["sigma"][k], 2)}' for k, v in c['params'].items()),
                       'yes' if c['significant'] else 'no', ', '.join(c['degenerate_with']))
                      for c in document['candidates']]
    residual = document['model']['residual']
    subsystems = document['subsystems'] or {}
    parts = [
        f'<h1>sofia noise: {html.escape(str(document["case"]))}</h1>',
        f'<p>{html.escape(str(document["description"]))}. Bag {html.escape(document["bag"])}: '
        f'{document["samples_per_axis"]} samples per axis, {document["record_s"]:.0f} s at '
        f'{document["sample_rate_hz"]:g} Hz (every {document["decimation"]}. read-out).</p>',
        '<h2>TA subsystem configuration (Table 5.2)</h2>',
        _table(('subsystem', 'state'), subsystems.items()) if subsystems else '<p>not recorded in this bag</p>',
        '<h2>Rates against Earth rate (Table 5.7 layout, deg/h)</h2>',
        _table(('', 'EL', 'XEL', 'LOS'), earth_rows),
        f'<p>Heading error and gyro biases are degenerate on a stationary record (5.2.4): the least-squares '
        f'heading only picks the smallest biases ({earth["heading_error_deg"]:+.2f} deg from the assumed).</p>',
        '<h2>Noise coefficients (Table 5.8 layout)</h2>',
        _table(('axis', 'ARW "/sqrt(s)', 'bias stability "/s', 'at tau s', 'RRW "/s^1.5', 'max angle "'),
               noise_rows),
        '<h2>Spectral lines (Tables 5.4, 5.5)</h2>',
        _table(('axis', 'Hz', 'amplitude "/s', 'likely source'), line_rows),
        f'<h2>Noise model {html.escape(str(document["model"]["path"]))}</h2>',
        f'<p>RMS ln(measured/predicted) root AV {residual["allan_rms_ln"]["all"]:.3f}, PSD '
        f'{residual["psd_rms_ln"]["all"]:.3f}; chi^2 per point {residual["chi2_per_point"]:.2f} '
        f'({residual["points"]} points).</p>',
        _table(('candidate', 'source', 'delta BIC', 'parameters', 'significant', 'degenerate with'),
               candidate_rows),
    ]
    for name, caption in PLOTS:
        parts.append(f'<figure><img src="{name}" alt="{html.escape(caption)}"><figcaption>{html.escape(caption)}'
                     '</figcaption></figure>')
    style = ('body{font-family:sans-serif;max-width:1100px;margin:auto}table{border-collapse:collapse;margin:8px 0}'
             'td,th{border:1px solid #bbb;padding:2px 6px;font-size:13px}img{max-width:100%}')
    return (f'<!DOCTYPE html><html><head><meta charset="utf-8"><title>sofia noise {html.escape(str(document["case"]))}'
            f'</title><style>{style}</style></head><body>{"".join(parts)}</body></html>\n')


def write_report(analysis: NoiseAnalysis, report_dir: str | PathLike[str]) -> Path:
    """Write index.html and the PNGs of PLOTS to report_dir, all or nothing (module docstring).

    Args:
        analysis: the analysis of a record (noise.run.analyze_record).
        report_dir: the --report directory (absent or empty).

    Returns:
        The report directory.

    Raises:
        ConfigError: the directory is in use or its parent is missing (check_report_dir).
    """
    target = check_report_dir(report_dir)
    building = Path(tempfile.mkdtemp(prefix=f'.{target.name}.', dir=target.parent))
    try:
        building.chmod(0o755)  # mkdtemp makes it private
        for (name, _), draw in zip(PLOTS, (_rates_figure, _angle_figure, _psd_figure, _spectrogram_figure,
                                           _allan_figure, _residual_figure)):
            draw(analysis, building / name)
        (building / 'index.html').write_text(_page(analysis.document))
        if target.exists():
            target.rmdir()
        building.rename(target)
    except BaseException:
        shutil.rmtree(building, ignore_errors=True)
        raise
    return target
