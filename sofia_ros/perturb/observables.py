"""What `sofia perturb` can change: a camera axis of the centroids or a gyro axis of the Imu samples, and its units."""

from __future__ import annotations

from dataclasses import dataclass

from sofia_ros.errors import PerturbationError
from sofia_ros.sensors.imager_model import CAMERAS, nominal_detector
from sofia_ros.topics import CENTROIDS, GYRO_IMU
from sofia_ros.units import RAD_PER_ARCSEC, RAD_PER_DEG

__all__ = ['CAMERA_AXES', 'GYRO_AXES', 'OBSERVABLES', 'Observable', 'observable']

#: Camera axis -> index in (pixel column X, row Y) of a centroid pose.
CAMERA_AXES = {'x': 0, 'y': 1}
#: Gyro axis (GYRF) -> index in angular_velocity (x, y, z).
GYRO_AXES = {'el': 0, 'xel': 1, 'los': 2}
#: Every observable name, cameras first.
OBSERVABLES = (*(f'{camera}.{axis}' for camera in CAMERAS for axis in CAMERA_AXES),
               *(f'gyro.{axis}' for axis in GYRO_AXES))
_SECONDS_PER_HOUR = 3600.0


@dataclass(frozen=True)
class Observable:
    """One observable: its topic, which field, and the recorded unit per unit a shape may be given in."""

    name: str
    topic: str
    #: the camera, or None for a gyro axis
    camera: str | None
    axis: int
    #: the recorded unit ('px' or 'rad_per_s')
    recorded_unit: str
    default_unit: str
    #: unit -> recorded units per one of it
    scales: tuple[tuple[str, float], ...]

    def recorded_per(self, unit: str | None) -> tuple[str, float]:
        """(unit, recorded units per one of it) for ``unit`` (None: the default); PerturbationError if not accepted."""
        unit = self.default_unit if unit is None else unit
        for name, scale in self.scales:
            if name == unit:
                return name, scale
        raise PerturbationError(f'unit {unit!r} is not accepted for {self.name}; use one of '
                                f'{", ".join(name for name, _ in self.scales)}')


def observable(name: str) -> Observable:
    """The Observable called ``name`` (e.g. fpi.x, gyro.los); PerturbationError naming the choices if unknown."""
    source, _, axis = str(name).partition('.')
    if source in CAMERAS and axis in CAMERA_AXES:
        scale_arcsec_per_px = nominal_detector(source).scale_arcsec_per_px
        return Observable(name, CENTROIDS[source].name, source, CAMERA_AXES[axis], 'px', 'arcsec',
                          (('arcsec', 1.0 / scale_arcsec_per_px), ('px', 1.0)))
    if source == 'gyro' and axis in GYRO_AXES:
        return Observable(name, GYRO_IMU.name, None, GYRO_AXES[axis], 'rad_per_s', 'deg_per_h',
                          (('deg_per_h', RAD_PER_DEG / _SECONDS_PER_HOUR), ('arcsec_per_s', RAD_PER_ARCSEC)))
    raise PerturbationError(f'unknown observable {name!r}; pick one of {", ".join(OBSERVABLES)}')
