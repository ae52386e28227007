"""Records that describe a physical effect and its parameters (docs/effects.md)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy.typing as npt

if TYPE_CHECKING:  # the contexts are only named here: no import at run time
    from sofia_ros.effects.context import CameraContext, GyroContext

__all__ = ['Parameter', 'EffectSpec', 'HOOKS', 'ParameterValue', 'EffectParams', 'Effects']

#: A parameter's value: a number, a text, a flag, or a list of numbers or texts (docs/effects.md).
ParameterValue = float | str | bool | list[float] | list[str]
#: One effect's parameters, name -> value (a resolved set holds every parameter of the spec).
EffectParams = dict[str, Any]
#: A truth or model: effect name -> its parameters (the schema of docs/effects.md).
Effects = dict[str, EffectParams]

#: Hook name -> number of columns its result has per row.
HOOKS = {'gyro_rate_offset': 3, 'camera_rotation': 3, 'camera_shift_px': 2}


@dataclass(frozen=True)
class Parameter:
    """One physical parameter of an effect, with its unit and thesis default."""

    name: str
    default: ParameterValue
    unit: str
    description: str
    #: True for a parameter that shapes the effect (period, phase, weather) rather than scaling it:
    #: the effect vanishes when its scaling parameters are zero, whatever the shaping ones are.
    shape: bool = False
    #: Allowed range in the parameter's unit (None: only finite); for a list, of every entry.
    minimum: float | None = None
    maximum: float | None = None
    #: Allowed values of a text parameter (or of every entry of a list of texts); empty: any.
    choices: tuple[str, ...] = ()


@dataclass(frozen=True)
class EffectSpec:
    """A named piece of physics: thesis section, description and parameters in physical units.

    The catalogue's own effects keep their physics in the shared error models
    (sensors.gyro_errors, sensors.imager_model). A plug-in effect brings its physics along in
    hooks, which the truth simulator and `sofia compare` both call with the same kind of
    context (effects.context: the recorded variables, their frames and signs):

    - ``gyro_rate_offset(params, context: GyroContext) -> (N, 3)``: rad/s every GYRF axis reads
      on top of the true rate; it may depend on time, temperature, specific force and the rates
      themselves (a scale-factor-like term). The gyro box adds it per sample; compare removes it
      at each 0.2 s tick's means, exact for offsets slow against a tick.
    - ``camera_rotation(params, context: CameraContext) -> (N, 3)``: arcsec rotation (EL, XEL,
      LOS) of a camera frame against TARF, added to its gravity flexure (zeros for cameras it
      does not touch).
    - ``camera_shift_px(params, context: CameraContext) -> (N, 2)``: pixels (X, Y) added to each
      centroid on the detector; its context also holds the detector position and the star.

    A hook that raises, returns the wrong shape or a non-finite value is reported as one line
    naming the effect (ConfigError).
    """

    name: str
    family: str
    thesis: str
    description: str
    params: tuple[Parameter, ...] = field(default_factory=tuple)
    gyro_rate_offset: Callable[[EffectParams, GyroContext], npt.ArrayLike] | None = None
    camera_rotation: Callable[[EffectParams, CameraContext], npt.ArrayLike] | None = None
    camera_shift_px: Callable[[EffectParams, CameraContext], npt.ArrayLike] | None = None
    #: check(resolved_params) -> None or a message: conditions between parameters (equal list lengths)
    check: Callable[[EffectParams], str | None] | None = None

    @property
    def hooks(self) -> tuple[str, ...]:
        """Names of the hooks this effect brings (empty for the built-in effects)."""
        return tuple(name for name in HOOKS if getattr(self, name) is not None)

    def defaults(self) -> EffectParams:
        """Parameter name -> default value (the thesis' magnitudes).

        Returns:
            Every parameter of the spec at its default, a new dict.
        """
        return {param.name: param.default for param in self.params}

    def parameter(self, name: str) -> Parameter | None:
        """The Parameter called ``name``, or None.

        Args:
            name: the parameter's name.

        Returns:
            The spec's Parameter of that name, or None if it has none.
        """
        return next((param for param in self.params if param.name == name), None)
