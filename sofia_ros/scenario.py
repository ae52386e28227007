"""Where and when a campaign happens: site, epoch, heading, elevation, weather-free geometry, thermal history.

The telescope's temperature drifts linearly through the night (``temperature_c_at``), as the cavity's
did at Waco (about 2 C in 2 h, 6.2, Fig. 6.5). A truth may give its thermal environment a control
(``scenario.thermal_control``): then a plan's temperature element commands a setpoint that the
temperature follows with a first-order lag (:class:`ThermalHistory`, docs/plans.md).
"""

from __future__ import annotations

import datetime as dt
import math
from dataclasses import dataclass
from typing import Any, Mapping

import yaml

from sofia_ros.errors import ConfigError
from sofia_ros.sky import Site
from sofia_ros.topics import SCENARIO_DOCUMENT

__all__ = ['Scenario', 'ThermalControl', 'ThermalHistory', 'lagged_temperature_c', 'scenario_document',
           'scenario_from_document', 'scenario_from_mapping']


@dataclass(frozen=True)
class ThermalControl:
    """What a truth's thermal environment lets a plan command: a setpoint in a range, slewed at most so fast.

    The thesis names no thermal control of the telescope on the ground, only what moves its temperature
    (the cooling carts of the TA oil, 5.2.1; the night's drift in the cavity, 6.2); a truth that has
    one (e.g. the cavity conditioned from a ground cart) states its limits here, illustratively.
    """

    #: the lowest and highest setpoint the control reaches, deg C
    min_c: float
    max_c: float
    #: the fastest the setpoint may move, deg C per hour
    max_rate_c_per_h: float
    #: the time constant with which the temperature follows the setpoint, s
    time_constant_s: float

    def refusal(self, target_c: float, rate_c_per_h: float) -> str | None:
        """Why a command to ``target_c`` at ``rate_c_per_h`` is out of reach, or None if it is not."""
        if not self.min_c <= target_c <= self.max_c:
            return (f'target_c {target_c:g} C is outside the {self.min_c:g} to {self.max_c:g} C '
                    "the truth's thermal control reaches")
        if not 0.0 < rate_c_per_h <= self.max_rate_c_per_h:
            return (f'rate_c_per_h {rate_c_per_h:g} C/h is outside (0, {self.max_rate_c_per_h:g}] C/h, '
                    "the truth's thermal control's rates")
        return None


@dataclass(frozen=True)
class Scenario:
    """The campaign's fixed circumstances (the truth varies the physics, not these)."""

    site: Site
    start_utc: dt.datetime
    heading_deg: float
    start_elevation_deg: float
    start_temperature_c: float = 22.8
    temperature_slope_c_per_h: float = -1.0
    #: the control a plan's temperature element commands (None: the temperature only drifts, no plan moves it)
    thermal_control: ThermalControl | None = None

    @property
    def latitude_deg(self):
        """Latitude of the bearing centre (4.1)."""
        return self.site.latitude_deg

    def temperature_c_at(self, elapsed_s):
        """Telescope structure temperature at ``elapsed_s``: a linear drift through the night."""
        return self.start_temperature_c + self.temperature_slope_c_per_h * elapsed_s / 3600.0


def lagged_temperature_c(elapsed_s: float, start_s: float, start_c: float, target_c: float, rate_c_per_h: float,
                         time_constant_s: float) -> float:
    """Temperature at ``elapsed_s`` (>= ``start_s``) of a first-order lag, dT/dt = (S - T)/tau, from ``start_c``
    behind a setpoint S slewed from ``start_c`` to ``target_c`` at ``rate_c_per_h``, then held (Newton's cooling)."""
    span_c = target_c - start_c
    slew_s = abs(span_c) / rate_c_per_h * 3600.0
    slope_c_per_s = math.copysign(rate_c_per_h / 3600.0, span_c)
    ramp_s = min(elapsed_s - start_s, slew_s)
    # On the ramp the lag trails the setpoint by slope * tau once its start has decayed.
    on_ramp_c = start_c + slope_c_per_s * (ramp_s + time_constant_s * math.expm1(-ramp_s / time_constant_s))
    held_s = elapsed_s - start_s - ramp_s
    return target_c + (on_ramp_c - target_c) * math.exp(-held_s / time_constant_s)


class ThermalHistory:
    """The temperature through a run: the scenario's drift until a command, then the lag behind each command.

    The plant and the cameras each keep one, fed the same commands (topics.THERMAL_COMMAND), so every
    temperature-dependent effect sees one temperature. A command starts at its own stamp: it reaches
    a reader before that reader's next tick (their upstream), so every mode computes the same values.
    """

    def __init__(self, scenario: Scenario):
        self.scenario = scenario
        #: (start_s, start_c, target_c, rate_c_per_h) per command, in the order they start
        self.commands: list[tuple[float, float, float, float]] = []

    def command(self, start_s: float, target_c: float, rate_c_per_h: float) -> None:
        """Slew the setpoint from the temperature at ``start_s`` to ``target_c`` at ``rate_c_per_h``, then hold it.

        As a controller does, the setpoint saturates: a target beyond the control's range is held at its end, a
        rate that is not in (0, largest] becomes the largest. Without a control nothing follows a setpoint (a plan
        that asks for one is refused before the run), and a target that is not a number is no command.
        """
        control = self.scenario.thermal_control
        if control is None or not math.isfinite(target_c):
            return
        target_c = min(max(target_c, control.min_c), control.max_c)
        if not 0.0 < rate_c_per_h <= control.max_rate_c_per_h:
            rate_c_per_h = control.max_rate_c_per_h
        self.commands.append((start_s, self.temperature_c_at(start_s), target_c, rate_c_per_h))

    def temperature_c_at(self, elapsed_s: float) -> float:
        """The temperature at ``elapsed_s``: the scenario's drift before the first command (to the bit)."""
        latest = next((command for command in reversed(self.commands) if command[0] <= elapsed_s), None)
        if latest is None:
            return self.scenario.temperature_c_at(elapsed_s)
        return lagged_temperature_c(elapsed_s, *latest, self.scenario.thermal_control.time_constant_s)


#: Allowed range of each numeric scenario key.
SCENARIO_RANGES = {
    'latitude_deg': (-90.0, 90.0), 'longitude_deg': (-180.0, 360.0), 'height_m': (-500.0, 20000.0),
    'heading_deg': (-360.0, 360.0), 'start_elevation_deg': (-90.0, 90.0), 'start_temperature_c': (-80.0, 60.0),
    'temperature_slope_c_per_h': (-100.0, 100.0),
}
#: Allowed range of each key of ``scenario.thermal_control`` (the largest rate and the time constant must be > 0).
THERMAL_CONTROL_RANGES = {
    'min_c': (-80.0, 60.0), 'max_c': (-80.0, 60.0), 'max_rate_c_per_h': (0.0, 100.0),
    'time_constant_s': (0.0, 86400.0),
}


def _scenario_number(key, value, ranges=SCENARIO_RANGES, where='scenario'):
    """A finite number inside ranges[key]; ConfigError naming the key and the range otherwise."""
    low, high = ranges[key]
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ConfigError(f'{where}: {key} must be a number in [{low:g}, {high:g}], got {str(value)[:40]!r}')
    number = float(value)
    if not low <= number <= high:  # also false for NaN
        raise ConfigError(f'{where}: {key} = {number:g} is outside [{low:g}, {high:g}]')
    return number


def thermal_control_from_mapping(values: Any) -> ThermalControl | None:
    """``scenario.thermal_control`` of a truth file (None: no control); ConfigError naming a missing or bad key."""
    if values is None:
        return None
    where = 'scenario: thermal_control'
    if not isinstance(values, dict) or set(values) != set(THERMAL_CONTROL_RANGES):
        raise ConfigError(f'{where} must map exactly {", ".join(THERMAL_CONTROL_RANGES)} '
                          f'(docs/plans.md), got {str(values)[:60]!r}')
    numbers = {key: _scenario_number(key, values[key], THERMAL_CONTROL_RANGES, where) for key in THERMAL_CONTROL_RANGES}
    if numbers['min_c'] >= numbers['max_c']:
        raise ConfigError(f'{where}: min_c {numbers["min_c"]:g} must be below max_c {numbers["max_c"]:g}')
    for key in ('max_rate_c_per_h', 'time_constant_s'):
        if numbers[key] <= 0.0:
            raise ConfigError(f'{where}: {key} must be > 0, got {numbers[key]:g}')
    return ThermalControl(**numbers)


def _thermal_control_mapping(control: ThermalControl) -> dict[str, float]:
    return {'min_c': control.min_c, 'max_c': control.max_c, 'max_rate_c_per_h': control.max_rate_c_per_h,
            'time_constant_s': control.time_constant_s}


def scenario_from_mapping(defaults: Scenario, overrides: Mapping[str, Any] | None) -> Scenario:
    """A Scenario from campaign defaults overlaid with a truth file's ``scenario:`` mapping."""
    if overrides is None:
        return defaults
    if not isinstance(overrides, dict):
        raise ConfigError(f'scenario must be a mapping, got {type(overrides).__name__}')
    fields = {
        'latitude_deg': defaults.site.latitude_deg, 'longitude_deg': defaults.site.longitude_deg,
        'height_m': defaults.site.height_m, 'start_utc': defaults.start_utc.isoformat(),
        'heading_deg': defaults.heading_deg, 'start_elevation_deg': defaults.start_elevation_deg,
        'start_temperature_c': defaults.start_temperature_c,
        'temperature_slope_c_per_h': defaults.temperature_slope_c_per_h,
        'thermal_control': (None if defaults.thermal_control is None
                            else _thermal_control_mapping(defaults.thermal_control)),
    }
    unknown = sorted(set(overrides) - set(fields))
    if unknown:
        raise ConfigError(f'scenario: unknown key(s) {", ".join(unknown)} (known: {", ".join(fields)})')
    fields.update(overrides)
    try:
        start_utc = dt.datetime.fromisoformat(str(fields['start_utc']).replace('Z', '+00:00'))
    except (TypeError, ValueError) as err:
        raise ConfigError(f'scenario: start_utc {str(fields["start_utc"])[:40]!r} is not a date and time ({err}); '
                          'give ISO 8601 with a timezone, e.g. 2004-09-03T04:22:16Z') from err
    numbers = {key: _scenario_number(key, fields[key]) for key in SCENARIO_RANGES}
    if start_utc.tzinfo is None:
        raise ConfigError('scenario: start_utc needs a timezone, e.g. 2004-09-03T04:22:16Z')
    if not 1900 <= start_utc.year <= 2100:
        raise ConfigError(f'scenario: start_utc must lie in 1900-2100 (the sky model\'s range), got {start_utc.year}')
    site = Site(numbers['latitude_deg'], numbers['longitude_deg'], numbers['height_m'])
    return Scenario(site, start_utc, numbers['heading_deg'], numbers['start_elevation_deg'],
                    numbers['start_temperature_c'], numbers['temperature_slope_c_per_h'],
                    thermal_control_from_mapping(fields['thermal_control']))




def scenario_document(scenario: Scenario) -> str:
    """The scenario as the YAML document recorded on topics.SCENARIO_DOCUMENT (thermal_control only if it has one)."""
    document = {
        'latitude_deg': scenario.site.latitude_deg, 'longitude_deg': scenario.site.longitude_deg,
        'height_m': scenario.site.height_m, 'start_utc': scenario.start_utc.isoformat(),
        'heading_deg': scenario.heading_deg, 'start_elevation_deg': scenario.start_elevation_deg,
        'start_temperature_c': scenario.start_temperature_c,
        'temperature_slope_c_per_h': scenario.temperature_slope_c_per_h,
    }
    if scenario.thermal_control is not None:
        document['thermal_control'] = _thermal_control_mapping(scenario.thermal_control)
    return yaml.safe_dump(document, sort_keys=False)


def scenario_from_document(text: str) -> Scenario:
    """A Scenario from a recorded scenario document; ConfigError if it is not one."""
    try:
        fields = yaml.safe_load(text)
    except yaml.YAMLError as err:
        raise ConfigError(f'{SCENARIO_DOCUMENT.name} is not valid YAML; re-record the bag') from err
    if not isinstance(fields, dict) or not {'latitude_deg', 'start_utc', 'heading_deg'} <= set(fields):
        raise ConfigError(f'{SCENARIO_DOCUMENT.name} lacks latitude_deg, start_utc or heading_deg; re-record the bag')
    placeholder = Scenario(Site(0.0, 0.0, 0.0), dt.datetime(2000, 1, 1, tzinfo=dt.timezone.utc), 0.0, 40.0)
    return scenario_from_mapping(placeholder, fields)
