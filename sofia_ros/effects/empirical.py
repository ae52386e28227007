"""Empirical terms: generic shapes of one recorded variable on one observable, like TPOINT's harmonic terms.

When the residual of a comparison holds structure that no physical effect explains, a generic
shape of the variable it follows can still be fitted, ranked by delta-BIC beside the physical
candidates, and kept in a model (`sofia model add`) while the physics is worked out. An
empirical term is an effect whose name says what it is:

    empirical:<observable>:<variable>:<shape>

- observable: a camera axis ``hipo.x``, ``fpi.y``, ... (pixel column X / row Y) or a gyro axis
  ``gyro.el``, ``gyro.xel``, ``gyro.los`` (GYRF);
- variable: see VARIABLES (cameras) and GYRO_TERM_VARIABLES (gyros), and for cameras
  ``detector_field``, the detector position x and y together;
- shape: ``poly3@LOW..HIGH`` (Legendre polynomials P0..P3 of the variable mapped from LOW..HIGH
  onto -1..1, the range the data covered; gyro terms leave out P0, which is gyro_bias), ``poly3``
  (the same over the variable's nominal range, VARIABLES; for ``detector_field`` the products
  P_i(x) P_j(y), i + j <= 3, over the chip: a distortion of the field) or ``period_<P>s`` (a
  sinusoid of period P seconds in time).

Every number of a name is bounded to what a record can resolve (PERIOD_RANGE_S, RANGE_LIMIT,
RANGE_RESOLUTION), so a name that parses is a term a fit can carry: a period of 1e-300 s, or
a range whose ends a float cannot tell apart, is refused when the name is read, by `sofia model
add` and by a model file alike.

Camera terms shift the centroids on the detector (arcsec along the pixel axis, through the
camera's nominal scale); gyro terms add a rate (deg/h) to one gyro axis. Both are ordinary
plug-in hooks (effects.context), so the truth simulator could carry them too.
"""

from __future__ import annotations

import functools
import re
from typing import NamedTuple

import numpy as np
import numpy.typing as npt
from numpy.polynomial import legendre

from sofia_ros.effects.base import EffectSpec, Parameter
from sofia_ros.effects.context import CameraContext, GyroContext
from sofia_ros.errors import UnknownEffectError
from sofia_ros.frames import AXES, FFI, FPI, HIPO_2004, WFI
from sofia_ros.units import RAD_PER_DEG, STANDARD_GRAVITY_M_PER_S2

__all__ = ['PREFIX', 'CAMERA_OBSERVABLES', 'GYRO_OBSERVABLES', 'VARIABLES', 'GYRO_TERM_VARIABLES', 'DETECTOR_FIELD',
           'POLY_DEGREE', 'PERIOD_RANGE_S', 'RANGE_LIMIT', 'RANGE_RESOLUTION', 'field_columns', 'field_terms',
           'empirical_spec', 'empirical_name', 'empirical_parts', 'is_empirical', 'term_identity', 'variable_values']

PREFIX = 'empirical:'
_DETECTORS = {'hipo': HIPO_2004, 'fpi': FPI, 'ffi': FFI, 'wfi': WFI}
CAMERA_OBSERVABLES = tuple(f'{camera}.{axis}' for camera in _DETECTORS for axis in ('x', 'y'))
GYRO_OBSERVABLES = tuple(f'gyro.{axis}' for axis in AXES)
POLY_DEGREE = 3
#: Shortest and longest period of a term [s]: HIPO's 1 s frames resolve 2 s at best (the gyro
#: series, one value per fit anchor, far less); 1e6 s (11.6 days) is beyond any record.
PERIOD_RANGE_S = (1.0, 1.0e6)
#: Largest magnitude of a poly3@LOW..HIGH end, in the variable's unit: beyond any ROS stamp in s
#: (an imported record's time is seconds since 1970), any angle, temperature, force or pixel.
RANGE_LIMIT = 1.0e10
#: Shortest span HIGH - LOW relative to the larger end (or 1): the variable mapped onto -1..1 keeps
#: seven of float64's sixteen digits, so the Legendre columns stay well defined.
RANGE_RESOLUTION = 1.0e-9
#: Longest name read: the longest valid one (a range of two 17-digit ends) has about 90 characters.
_MAX_NAME_CHARS = 160
_RAD_PER_S_PER_DEG_PER_H = RAD_PER_DEG / 3600.0


def _force_g(axis):
    return lambda context: context.specific_force_m_per_s2[:, axis] / STANDARD_GRAVITY_M_PER_S2


#: Variable -> (value of a context, centre, half range, unit). The fixed ranges keep a fitted
#: term meaningful in another campaign: the coarse drive's 16.5-68.5 deg, the fine drive's +-3 deg.
VARIABLES = {
    'elevation': (lambda c: c.elevation_deg, 42.5, 26.0, 'deg'),
    'time': (lambda c: c.time_s, 0.0, 3600.0, 's'),
    'temperature': (lambda c: c.temperature_c, 22.8, 10.0, 'C'),
    'los_angle': (lambda c: c.los_angle_deg, 0.0, 3.0, 'deg'),
    'specific_force_el': (_force_g(0), 0.0, 1.0, 'g'),
    'specific_force_xel': (_force_g(1), 0.0, 1.0, 'g'),
    'specific_force_los': (_force_g(2), 0.0, 1.0, 'g'),
    'detector_x': (lambda c: c.detector_x_px, None, None, 'px'),
    'detector_y': (lambda c: c.detector_y_px, None, None, 'px'),
}
GYRO_TERM_VARIABLES = ('time', 'temperature', 'specific_force_el', 'specific_force_xel', 'specific_force_los')
#: The detector position as one variable of a camera term: x and y together, over the chip.
DETECTOR_FIELD = 'detector_field'
# Exponents may carry a sign: empirical_name writes 1.44e+04 for 14400.
_NUMBER = r'-?[0-9]+(?:\.[0-9]+)?(?:e[-+]?[0-9]+)?'
_NAME = re.compile(r'^empirical:(?P<observable>[a-z]+\.[a-z]+):(?P<variable>[a-z_]+):'
                   rf'(?P<shape>poly(?P<order>[0-9]+)(?:@(?P<low>{_NUMBER})\.\.(?P<high>{_NUMBER}))?'
                   rf'|period_(?P<period>{_NUMBER})s)$')
_HINT = ('empirical terms are named empirical:<observable>:<variable>:<poly3|period_<P>s>, e.g. '
         'empirical:ffi.y:elevation:poly3 or empirical:hipo.x:time:period_95s (poly3@LOW..HIGH: over that range)')


class _Parts(NamedTuple):
    """What a valid empirical name says."""

    observable: str
    variable: str
    #: seconds, for a sinusoid; else None
    period_s: float | None
    #: (low, high) of a poly3@LOW..HIGH term; else None
    range_: tuple[float, float] | None


def is_empirical(name: object) -> bool:
    """True for a name of the empirical form.

    Args:
        name: an effect name (anything else is not empirical).

    Returns:
        Whether it is a text starting with ``empirical:`` (the rest is checked by empirical_parts).
    """
    return isinstance(name, str) and name.startswith(PREFIX)


def empirical_parts(name: str) -> tuple[str, str, float | None]:
    """(observable, variable, period in s or None) of an empirical term name; UnknownEffectError if it is not one.

    Args:
        name: an ``empirical:<observable>:<variable>:<shape>`` name.

    Returns:
        The observable, the variable and the period [s] of a sinusoid (None for a polynomial).

    Raises:
        UnknownEffectError: the name breaks the grammar or a bound (the message says which and what is allowed).
    """
    return _parsed(name)[:3]


def term_identity(name: str) -> object:
    """What makes a term one: its name, or an empirical term's parts (period_95s, period_095s and period_95.0s are one
    sinusoid, poly3@20..60 and poly3@20.0..60 one polynomial).

    Args:
        name: an effect name.

    Returns:
        A value equal for two names of the same term.
    """
    return ('empirical', *_parsed(name)) if is_empirical(name) else name


def _parsed(name):
    """The parts of an empirical name, each checked; UnknownEffectError says what is wrong and what is allowed."""
    if len(name) > _MAX_NAME_CHARS:
        raise UnknownEffectError(f'the effect name {name[:40]!r}... has {len(name)} characters; an empirical term\'s '
                                 f'name has at most {_MAX_NAME_CHARS}; {_HINT}')
    match = _NAME.match(name)
    if match is None:
        raise UnknownEffectError(f'unknown effect {name!r}; {_HINT}')
    observable, variable = match['observable'], match['variable']
    if match['order'] is not None and match['order'] != str(POLY_DEGREE):
        raise UnknownEffectError(f'{name!r}: the polynomial order must be {POLY_DEGREE} (poly{POLY_DEGREE}: Legendre '
                                 f'P0..P{POLY_DEGREE}); {_HINT}')
    period_s = _period(name, match['period']) if match['period'] else None
    range_ = _range(name, match['low'], match['high']) if match['low'] else None
    gyro = observable in GYRO_OBSERVABLES
    if observable not in CAMERA_OBSERVABLES and not gyro:
        raise UnknownEffectError(f'{name!r}: unknown observable {observable!r} (known: '
                                 f'{", ".join(CAMERA_OBSERVABLES + GYRO_OBSERVABLES)})')
    allowed = ('time',) if period_s is not None else (GYRO_TERM_VARIABLES if gyro else (*VARIABLES, DETECTOR_FIELD))
    if variable not in allowed:
        raise UnknownEffectError(f'{name!r}: variable {variable!r} is not available here (known: {", ".join(allowed)})')
    if variable == DETECTOR_FIELD and range_ is not None:
        raise UnknownEffectError(f'{name!r}: a detector field spans the chip; '
                                 f'name it {empirical_name(observable, variable)}')
    return _Parts(observable, variable, period_s, range_)


def _period(name, text):
    """The period of a name's period_<P>s, within PERIOD_RANGE_S."""
    period_s = float(text)  # the grammar admits digits only: at worst inf, never an error
    shortest, longest = PERIOD_RANGE_S
    if not shortest <= period_s <= longest:
        raise UnknownEffectError(f'{name!r}: the period must be between {shortest:g} and {longest:g} s (what a record '
                                 f'resolves), got {text} s; name a period in that range')
    return period_s


def _range(name, low_text, high_text):
    """(low, high) of a name's poly3@LOW..HIGH: finite within RANGE_LIMIT, HIGH above LOW by RANGE_RESOLUTION."""
    low, high = float(low_text), float(high_text)
    bounded = all(abs(end) <= RANGE_LIMIT for end in (low, high))
    if not bounded or not high - low >= RANGE_RESOLUTION * max(1.0, abs(low), abs(high)):
        raise UnknownEffectError(f'{name!r}: the range must be LOW..HIGH with HIGH > LOW, both within '
                                 f'+-{RANGE_LIMIT:g} and HIGH - LOW at least {RANGE_RESOLUTION:g} of the larger end '
                                 f'(or of 1); got {low_text}..{high_text}; name the range the data covered')
    return low, high


def empirical_name(observable: str, variable: str, period_s: float | None = None,
                   range_: tuple[float, float] | None = None) -> str:
    """The effect name of a polynomial (over ``range_`` (low, high), or the nominal range) or periodic term.

    Args:
        observable: a camera axis (``hipo.x``) or a gyro axis (``gyro.el``).
        variable: the variable the term follows (VARIABLES, DETECTOR_FIELD).
        period_s: the period [s] of a sinusoid in time; None for a polynomial.
        range_: (low, high) the polynomial's variable is mapped from; None for its nominal range.

    Returns:
        The ``empirical:...`` name (numbers to as many digits as keep a range's ends apart).
    """
    if period_s is not None:
        shape = f'period_{period_s:.4g}s'
    elif range_ is not None:
        shape = f'poly{POLY_DEGREE}@{_range_text(*range_)}'
    else:
        shape = f'poly{POLY_DEGREE}'
    return f'{PREFIX}{observable}:{variable}:{shape}'


def _range_text(low, high):
    """LOW..HIGH to 4 significant digits, or as many more as keep the two ends apart (a time since 1970: 7 or more)."""
    for digits in range(4, 18):
        low_text, high_text = f'{low:.{digits}g}', f'{high:.{digits}g}'
        if float(low_text) < float(high_text):
            break
    return f'{low_text}..{high_text}'


def _scaled(variable, camera, values, range_):
    """The variable mapped onto [-1, 1] over the given range, else its nominal one (detector axes: the chip)."""
    _, centre, half, _ = VARIABLES[variable]
    if range_ is not None:
        centre, half = (range_[0] + range_[1]) / 2.0, (range_[1] - range_[0]) / 2.0
    elif centre is None:
        detector = _DETECTORS[camera]
        x_axis = variable == 'detector_x'
        centre = detector.center_x_px if x_axis else detector.center_y_px
        half = (detector.width_px if x_axis else detector.height_px) / 2.0
    return (np.asarray(values, dtype=float) - centre) / half


def field_columns(x: npt.ArrayLike, y: npt.ArrayLike, degree: int = POLY_DEGREE) -> np.ndarray:
    """Columns P_i(x) P_j(y) for i + j <= degree, (i, j) in ``field_terms(degree)`` order; x, y scaled to [-1, 1].

    Args:
        x: N positions along X, scaled to [-1, 1].
        y: N positions along Y, scaled to [-1, 1].
        degree: the highest total degree i + j.

    Returns:
        (N, (degree + 1)(degree + 2) / 2) Legendre products.
    """
    x, y = np.asarray(x, dtype=float), np.asarray(y, dtype=float)
    eye = np.eye(degree + 1)
    return np.column_stack([legendre.legval(x, eye[i]) * legendre.legval(y, eye[j]) for i, j in field_terms(degree)])


def field_terms(degree: int = POLY_DEGREE) -> list[tuple[int, int]]:
    """The (i, j) degrees of a two-variable Legendre field, total degree first: (0, 0), (1, 0), (0, 1), (2, 0) ...

    Args:
        degree: the highest total degree i + j.

    Returns:
        The (i, j) pairs in column order of field_columns.
    """
    return [(total - j, j) for total in range(degree + 1) for j in range(total + 1)]


def variable_values(variable: str, context: GyroContext | CameraContext) -> np.ndarray:
    """The values of a variable in a hook context.

    Args:
        variable: a key of VARIABLES.
        context: the hook context holding it.

    Returns:
        The variable's N values as floats, in its unit (VARIABLES).
    """
    return np.asarray(VARIABLES[variable][0](context), dtype=float)


def _basis(variable, camera, context, degrees, period_s, range_):
    """Shape columns (N, k): Legendre P_degrees of the scaled variable, sin/cos of time, or the detector field."""
    if variable == DETECTOR_FIELD:
        return field_columns(_scaled('detector_x', camera, context.detector_x_px, None),
                             _scaled('detector_y', camera, context.detector_y_px, None), POLY_DEGREE)
    values = variable_values(variable, context)
    if period_s is not None:
        phase = 2.0 * np.pi * values / period_s
        return np.column_stack([np.sin(phase), np.cos(phase)])
    scaled = _scaled(variable, camera, values, range_)
    return np.column_stack([legendre.legval(scaled, np.eye(POLY_DEGREE + 1)[degree]) for degree in degrees])


@functools.lru_cache(maxsize=256)
def empirical_spec(name: str) -> EffectSpec:
    """The EffectSpec of an empirical term name; UnknownEffectError explains the grammar otherwise.

    Args:
        name: an ``empirical:<observable>:<variable>:<shape>`` name.

    Returns:
        The spec: one coefficient parameter per shape column and its gyro_rate_offset or camera_shift_px hook.

    Raises:
        UnknownEffectError: the name breaks the grammar or a bound.
    """
    observable, variable, period_s, range_ = _parsed(name)
    gyro = observable in GYRO_OBSERVABLES
    unit = 'deg/h' if gyro else 'arcsec'
    if period_s is not None:
        labels, degrees = ('sin', 'cos'), None
        what = f'a sinusoid of period {period_s:g} s'
    elif variable == DETECTOR_FIELD:
        labels, degrees = tuple(f'p{i}{j}' for i, j in field_terms(POLY_DEGREE)), None
        what = f'Legendre products P_i(x) P_j(y), i + j <= {POLY_DEGREE}, of the detector position over the chip'
    else:
        degrees = tuple(range(1 if gyro else 0, POLY_DEGREE + 1))
        labels = tuple(f'p{degree}' for degree in degrees)
        span = f'{range_[0]:g}..{range_[1]:g}' if range_ else 'its nominal range'
        what = f'Legendre polynomials P{degrees[0]}-P{POLY_DEGREE} of {variable} over {span}'
    params = tuple(Parameter(f'{label}_{"deg_per_h" if gyro else "arcsec"}', 0.0, unit,
                             f'coefficient of {label} ({unit})') for label in labels)
    if gyro:
        axis = AXES.index(observable.split('.')[1])

        def rate_offset(values, context):
            coefficients = np.array([values[param.name] for param in params])
            offsets = np.zeros((len(context), 3))
            offsets[:, axis] = _basis(variable, None, context, degrees, period_s, range_) @ coefficients
            return offsets * _RAD_PER_S_PER_DEG_PER_H

        hooks = {'gyro_rate_offset': rate_offset}
    else:
        camera, pixel_axis = observable.split('.')
        column = ('x', 'y').index(pixel_axis)
        scale_arcsec_per_px = _DETECTORS[camera].scale_arcsec_per_px

        def shift_px(values, context):
            shift = np.zeros((len(context), 2))
            if context.camera == camera:
                coefficients = np.array([values[param.name] for param in params])
                shift[:, column] = _basis(variable, camera, context, degrees, period_s, range_) @ coefficients
            return shift / scale_arcsec_per_px

        hooks = {'camera_shift_px': shift_px}
    return EffectSpec(name, 'empirical', 'empirical (no thesis section)',
                      f'{what} added to {observable} ({unit}): a shape the residual followed, to be '
                      'replaced by the physics behind it', params, **hooks)
