"""Sensor error models: truth to measurement for the gyro box, imagers and HIPO (DESIGN section 2)."""

__all__ = []
