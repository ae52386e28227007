"""Where and when a campaign happens: site, epoch, heading, elevation, weather-free geometry."""

from __future__ import annotations

import datetime as dt
from dataclasses import dataclass
from typing import Any, Mapping

import yaml

from sofia_ros.errors import ConfigError
from sofia_ros.sky import Site
from sofia_ros.topics import SCENARIO_DOCUMENT

__all__ = ['Scenario', 'scenario_document', 'scenario_from_document', 'scenario_from_mapping']


@dataclass(frozen=True)
class Scenario:
    """The campaign's fixed circumstances (the truth varies the physics, not these)."""

    site: Site
    start_utc: dt.datetime
    heading_deg: float
    start_elevation_deg: float
    start_temperature_c: float = 22.8
    temperature_slope_c_per_h: float = -1.0

    @property
    def latitude_deg(self):
        """Latitude of the bearing centre (4.1)."""
        return self.site.latitude_deg

    def temperature_c_at(self, elapsed_s):
        """Telescope structure temperature at ``elapsed_s``: a linear drift through the night."""
        return self.start_temperature_c + self.temperature_slope_c_per_h * elapsed_s / 3600.0


#: Allowed range of each numeric scenario key.
SCENARIO_RANGES = {
    'latitude_deg': (-90.0, 90.0), 'longitude_deg': (-180.0, 360.0), 'height_m': (-500.0, 20000.0),
    'heading_deg': (-360.0, 360.0), 'start_elevation_deg': (-90.0, 90.0), 'start_temperature_c': (-80.0, 60.0),
    'temperature_slope_c_per_h': (-100.0, 100.0),
}


def _scenario_number(key, value):
    """A finite number inside SCENARIO_RANGES[key]; ConfigError naming the key and the range otherwise."""
    low, high = SCENARIO_RANGES[key]
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ConfigError(f'scenario: {key} must be a number in [{low:g}, {high:g}], got {str(value)[:40]!r}')
    number = float(value)
    if not low <= number <= high:  # also false for NaN
        raise ConfigError(f'scenario: {key} = {number:g} is outside [{low:g}, {high:g}]')
    return number


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
    numbers = {key: _scenario_number(key, fields[key]) for key in fields if key != 'start_utc'}
    if start_utc.tzinfo is None:
        raise ConfigError('scenario: start_utc needs a timezone, e.g. 2004-09-03T04:22:16Z')
    if not 1900 <= start_utc.year <= 2100:
        raise ConfigError(f'scenario: start_utc must lie in 1900-2100 (the sky model\'s range), got {start_utc.year}')
    site = Site(numbers['latitude_deg'], numbers['longitude_deg'], numbers['height_m'])
    return Scenario(site, start_utc, numbers['heading_deg'], numbers['start_elevation_deg'],
                    numbers['start_temperature_c'], numbers['temperature_slope_c_per_h'])




def scenario_document(scenario: Scenario) -> str:
    """The scenario as the YAML document recorded on topics.SCENARIO_DOCUMENT."""
    return yaml.safe_dump({
        'latitude_deg': scenario.site.latitude_deg, 'longitude_deg': scenario.site.longitude_deg,
        'height_m': scenario.site.height_m, 'start_utc': scenario.start_utc.isoformat(),
        'heading_deg': scenario.heading_deg, 'start_elevation_deg': scenario.start_elevation_deg,
        'start_temperature_c': scenario.start_temperature_c,
        'temperature_slope_c_per_h': scenario.temperature_slope_c_per_h,
    }, sort_keys=False)


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
