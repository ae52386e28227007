"""Sensor error models: truth to measurement for the gyro box, imagers and HIPO."""

__all__ = []
