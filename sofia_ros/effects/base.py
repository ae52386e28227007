"""Records that describe a physical effect and its parameters (DESIGN.md section 5)."""

from __future__ import annotations

from dataclasses import dataclass, field

__all__ = ['Parameter', 'EffectSpec']


@dataclass(frozen=True)
class Parameter:
    """One physical parameter of an effect, with its unit and thesis default."""

    name: str
    default: object
    unit: str
    description: str
    #: True for a parameter that shapes the effect (period, phase, weather) rather than scaling it:
    #: the effect vanishes when its scaling parameters are zero, whatever the shaping ones are.
    shape: bool = False


@dataclass(frozen=True)
class EffectSpec:
    """A named piece of physics: thesis section, description and parameters in physical units."""

    name: str
    family: str
    thesis: str
    description: str
    params: tuple = field(default_factory=tuple)

    def defaults(self):
        """Parameter name -> default value (the thesis' magnitudes)."""
        return {param.name: param.default for param in self.params}

    def parameter(self, name):
        """The Parameter called ``name``, or None."""
        return next((param for param in self.params if param.name == name), None)
