"""Generic tools for gyro and centroid data: Allan variance, spectra, lines, structure, ranking, centroid drift."""

__all__ = ['allan', 'centroid_drift', 'lines', 'ranking', 'spectra', 'structure']
