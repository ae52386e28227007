"""`sofia noise`: a stability record's rates against Earth rate, its noise coefficients and lines (5.2)."""

from __future__ import annotations

import yaml

from sofia_ros.analysis.allan import log_spaced_cluster_sizes, overlapping_allan_deviation
from sofia_ros.analysis.lines import find_lines
from sofia_ros.analysis.noise_model import bias_stability, fit_noise_model
from sofia_ros.analysis.spectra import welch_rate_psd
from sofia_ros.bag import BagReader
from sofia_ros.earth_rate import best_fit_heading_deg, earth_rate_tarf_deg_per_h
from sofia_ros.errors import BagError
from sofia_ros.units import DEG_PER_RAD, GYRO_SAMPLE_RATE_HZ, RAD_PER_ARCSEC

__all__ = ['AXES', 'analyze_noise']

AXES = ('el', 'xel', 'los')
_N_TAUS = 60


def analyze_noise(bag_path, imu_topic='/gyro_box/imu'):
    """The `sofia noise --json` document of a bag (DESIGN.md section 6)."""
    with BagReader(bag_path) as bag:
        names = {topic.name for topic in bag.topics}
        if imu_topic not in names:
            raise BagError(f'{bag_path} has no {imu_topic}; record a gyro-stability campaign first')
        if '/config/case' not in names:
            raise BagError(f'{bag_path} has no /config/case; `sofia noise` reads the geometry of a gyro-stability run')
        case = yaml.safe_load(bag.document('/config/case'))
        imu = bag.imu_arrays(imu_topic)
    rates_arcsec_per_s = imu.angular_velocity_rad_per_s / RAD_PER_ARCSEC
    if len(rates_arcsec_per_s) < 3 * 400:
        raise BagError(f'{bag_path}: only {len(rates_arcsec_per_s)} samples; record at least a few seconds')
    measured_deg_per_h = imu.angular_velocity_rad_per_s.mean(axis=0) * DEG_PER_RAD * 3600.0
    theoretical = earth_rate_tarf_deg_per_h(case['latitude_deg'], case['heading_deg'], case['elevation_deg'])
    heading = best_fit_heading_deg(measured_deg_per_h, case['latitude_deg'], case['elevation_deg'])
    # Noise about the mean rate: Earth rate and the constant biases are not noise (5.2.6).
    noise = rates_arcsec_per_s - rates_arcsec_per_s.mean(axis=0)
    curves = overlapping_allan_deviation(noise, GYRO_SAMPLE_RATE_HZ,
                                         log_spaced_cluster_sizes(len(noise), _N_TAUS))
    freq_hz, psd = welch_rate_psd(noise)
    axes = {}
    for index, (axis, curve) in enumerate(zip(AXES, curves)):
        fit = fit_noise_model(curve)
        stability = bias_stability(curve)
        axes[axis] = {
            'arw_arcsec_per_sqrt_s': fit.arw_arcsec_per_sqrt_s, 'arw_sigma': fit.arw_sigma_arcsec_per_sqrt_s,
            'bias_stability_arcsec_per_s': stability.bias_stability_arcsec_per_s,
            'bias_stability_tau_s': stability.tau_s,
            'rrw_arcsec_per_s_sqrt_s': fit.rrw_arcsec_per_s_sqrt_s, 'rrw_sigma': fit.rrw_sigma_arcsec_per_s_sqrt_s,
            'lines': [{'freq_hz': line.freq_hz, 'amplitude_arcsec_per_s': line.amplitude_arcsec_per_s,
                       'source': line.source} for line in find_lines(freq_hz, psd[:, index])],
        }
    return {
        'case': case.get('case'), 'samples_per_axis': int(len(noise)),
        'axes': axes,
        'earth_rate_deg_per_h': {
            'measured': dict(zip(AXES, map(float, measured_deg_per_h))),
            'theoretical': dict(zip(AXES, map(float, theoretical))),
            'heading_deg': float(case['heading_deg']), 'best_fit_heading_deg': heading,
        },
        # The noise-model loop (ranked missing terms) is not built yet.
        'candidates': [],
    }
