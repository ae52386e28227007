"""Offline analysis of gyro data: Allan variance, noise model and spectra (section 4.2, chapter 5)."""

__all__ = ['allan', 'noise_model', 'spectra']
