"""Stars on the sky: Hipparcos 2 catalogue, observed places through ERFA, Stone and ERFA
refraction (thesis 4.3.2) and star-pair angular distances (4.3.3, 6.3)."""

from sofia_ros.sky.catalogue import STAR_NAMES, StarEntry, find_star, star_by_hip, star_by_name
from sofia_ros.sky.distances import (
    FPI_SCALE_ARCSEC_PER_PX,
    angular_distance_arcsec,
    place_distance_arcsec,
    refraction_adjusted_distance_arcsec,
    short_move_euler_arcsec,
    spherical_sum_arcsec,
)
from sofia_ros.sky.places import (
    EDWARDS_2007_SITE,
    TELESCOPE_MIN_ELEVATION_DEG,
    WACO_2004_SITE,
    WACO_2004_WEATHER,
    ObservedPlace,
    Site,
    VisibleStar,
    Weather,
    astrometric_observed_place,
    mean_place_of_date_deg,
    observed_directions_hrf,
    observed_place,
    visible_stars,
)
from sofia_ros.sky.refraction import (
    air_refractivity,
    apparent_altitude_deg,
    erfa_refraction_arcsec,
    stone_refraction_arcsec,
    stone_refraction_from_topocentric_arcsec,
)

__all__ = [
    'STAR_NAMES',
    'StarEntry',
    'find_star',
    'star_by_hip',
    'star_by_name',
    'Site',
    'Weather',
    'ObservedPlace',
    'VisibleStar',
    'WACO_2004_SITE',
    'WACO_2004_WEATHER',
    'EDWARDS_2007_SITE',
    'TELESCOPE_MIN_ELEVATION_DEG',
    'observed_place',
    'astrometric_observed_place',
    'mean_place_of_date_deg',
    'visible_stars',
    'observed_directions_hrf',
    'air_refractivity',
    'stone_refraction_arcsec',
    'stone_refraction_from_topocentric_arcsec',
    'erfa_refraction_arcsec',
    'apparent_altitude_deg',
    'FPI_SCALE_ARCSEC_PER_PX',
    'angular_distance_arcsec',
    'spherical_sum_arcsec',
    'short_move_euler_arcsec',
    'refraction_adjusted_distance_arcsec',
    'place_distance_arcsec',
]
