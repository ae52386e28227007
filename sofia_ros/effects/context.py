"""What a plug-in hook may depend on: the recorded variables at each sample, frame or centroid.

The truth simulator and `sofia compare` build the same contexts, so a hook written once
perturbs the sensors on the truth side and is removed (fitted) on the model side.

Frames and signs (docs/effects.md):

* ``specific_force_m_per_s2`` is in TARF (x = EL axis, y = XEL axis, z = LOS): at rest it is
  -g, i.e. (0, -g cos el, +g sin el) (eq. 2.13). The truth side has it from the plant; compare
  turns the gyro box's accelerometer samples into TARF with the model's gyro misalignment.
* ``rates_rad_per_s`` (gyro hooks) are GYRF rates: the true ones on the truth side, the
  measured ones on the model side (they differ by the gyro errors, a second-order difference
  for a hook that scales a rate).
* A camera rotation (EL, XEL, LOS) ["] turns the camera frame as if the telescope had turned
  by it: +EL moves a star on the LOS to +Y rows in FPI/FFI/WFI, +XEL to -X columns.
* A camera shift (dX, dY) px is added to the centroid on the detector: +X columns, +Y rows.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from sofia_ros.flexure import gravity_load_tarf

__all__ = ['GyroContext', 'CameraContext', 'resting_specific_force_tarf_m_per_s2']


def resting_specific_force_tarf_m_per_s2(elevation_deg: npt.ArrayLike) -> np.ndarray:
    """Specific force of a telescope at rest, f = -g in TARF: (0, -g cos el, g sin el) (eq. 2.13, 3.24).

    Args:
        elevation_deg: telescope elevation [deg], a number or an array of N.

    Returns:
        The specific force [m/s^2], (3,) for a number, (N, 3) for an array.
    """
    return -gravity_load_tarf(elevation_deg)


@dataclass(frozen=True, eq=False)
class GyroContext:
    """Per gyro sample (truth) or tick (compare): time, temperature, specific force (TARF), GYRF rates."""

    time_s: np.ndarray
    temperature_c: np.ndarray
    specific_force_m_per_s2: np.ndarray
    rates_rad_per_s: np.ndarray

    def __len__(self) -> int:
        return len(self.time_s)

    @classmethod
    def at_rest(cls, times_s: npt.ArrayLike, temperature_c: npt.ArrayLike, elevation_deg: float = 40.0,
                rates_rad_per_s: npt.ArrayLike | None = None) -> GyroContext:
        """A context without recorded forces: the telescope at rest at one elevation.

        Args:
            times_s: sample times [s], a number or N of them.
            temperature_c: gyro temperature [deg C], one for all samples or one per sample.
            elevation_deg: the elevation the telescope rests at [deg].
            rates_rad_per_s: (N, 3) GYRF rates [rad/s]; None for zeros.

        Returns:
            The context of N samples.
        """
        times = np.atleast_1d(np.asarray(times_s, dtype=float))
        force = np.tile(resting_specific_force_tarf_m_per_s2(float(elevation_deg)), (len(times), 1))
        rates = np.zeros((len(times), 3)) if rates_rad_per_s is None else np.asarray(rates_rad_per_s, dtype=float)
        return cls(times, np.broadcast_to(np.asarray(temperature_c, dtype=float), times.shape), force, rates)


@dataclass(frozen=True, eq=False)
class CameraContext:
    """Per frame (truth) or centroid row (compare) of one camera: what a camera hook may depend on.

    ``detector_x_px``, ``detector_y_px`` and ``hip`` are given to shift hooks only (a rotation
    acts before the star lands on the detector); they are None for rotation hooks.
    """

    camera: str
    time_s: np.ndarray
    elevation_deg: np.ndarray
    temperature_c: np.ndarray
    specific_force_m_per_s2: np.ndarray
    los_angle_deg: np.ndarray
    detector_x_px: np.ndarray | None = None
    detector_y_px: np.ndarray | None = None
    hip: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.elevation_deg)

    @classmethod
    def at_rest(cls, camera: str, elevation_deg: npt.ArrayLike, *, time_s: npt.ArrayLike = 0.0,
                temperature_c: npt.ArrayLike = np.nan, los_angle_deg: npt.ArrayLike = 0.0) -> CameraContext:
        """A context from the elevation alone (the telescope at rest), for one or many elevations.

        Args:
            camera: the camera's name (fpi, ffi, wfi).
            elevation_deg: telescope elevation [deg], a number or N of them.
            time_s: frame time [s], one for all rows or one per row.
            temperature_c: temperature [deg C], one for all rows or one per row (NaN: not recorded).
            los_angle_deg: LOS rotation angle [deg], one for all rows or one per row.

        Returns:
            The context of N rows, without detector positions.
        """
        elevation = np.atleast_1d(np.asarray(elevation_deg, dtype=float))
        return cls(camera, np.broadcast_to(np.asarray(time_s, dtype=float), elevation.shape), elevation,
                   np.broadcast_to(np.asarray(temperature_c, dtype=float), elevation.shape),
                   resting_specific_force_tarf_m_per_s2(elevation),
                   np.broadcast_to(np.asarray(los_angle_deg, dtype=float), elevation.shape))

    def with_detector(self, pixels_px: npt.ArrayLike, hip: npt.ArrayLike) -> CameraContext:
        """The same rows with the centroids they land on (for shift hooks).

        Args:
            pixels_px: (N, 2) centroids (X, Y) [px], one per row.
            hip: the Hipparcos number of each row's star.

        Returns:
            A new context with detector_x_px, detector_y_px and hip set.
        """
        pixels = np.asarray(pixels_px, dtype=float).reshape(-1, 2)
        return CameraContext(self.camera, self.time_s, self.elevation_deg, self.temperature_c,
                             self.specific_force_m_per_s2, self.los_angle_deg, pixels[:, 0], pixels[:, 1],
                             np.asarray(hip))

    def rows(self, selection: np.ndarray | slice) -> CameraContext:
        """The context of a subset of rows.

        Args:
            selection: a boolean mask, indices or a slice of the rows.

        Returns:
            A new context holding the selected rows of every column.
        """
        def pick(values: np.ndarray | None) -> np.ndarray | None:
            return None if values is None else np.asarray(values)[selection]

        return CameraContext(self.camera, pick(self.time_s), pick(self.elevation_deg), pick(self.temperature_c),
                             pick(self.specific_force_m_per_s2), pick(self.los_angle_deg), pick(self.detector_x_px),
                             pick(self.detector_y_px), pick(self.hip))
