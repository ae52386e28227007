"""The `sofia design` command: the plan elements that would separate a competing set, then the check (docs/design.md).

`sofia design SOURCE` takes a comparison's JSON (`sofia compare --json`) or a bag with --model,
and a competing set (the comparison's first, --set N of it, or --between A,B). It flies the
library of plan elements once on the nominal truth (each temperature step in a flight of its
own, from the bag's end time and last temperature; kept in the user's cache), predicts, prints
the table, and writes the plan. `sofia design --check NEW_BAG --prediction DESIGN.json` refits
the members on the old and the new bag and prints predicted against achieved separation.

This front end is the layer that may fly campaigns (campaigns/); the prediction itself
(design.run, design.geometry, design.separation, design.elements) reads bags only.
"""

from __future__ import annotations

import argparse
import functools
import hashlib
import json
import os
import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TextIO

from sofia_ros.cli_args import integer, number
from sofia_ros.compare.cli import DEFAULT_ANCHOR_S, MAX_ANCHOR_S, MIN_ANCHOR_S
from sofia_ros.errors import BagError, ConfigError
from sofia_ros.forked import forked_map, usable_cores
from sofia_ros.held_folders import held_folder, release_folder, remove_abandoned_folders
from sofia_ros.output_files import checked_output_file, json_ready, write_text_atomically
from sofia_ros.progress import Progress

__all__ = ['add_design_arguments', 'run_design']

_MAX_JSON_BYTES = 64 << 20
#: The library flight's own sequence at its least sim time (the alignment: one iteration, the fewest maneuvers, no
#: boresight series; the star hop: observations back to back)...
_LIBRARY_BASE = {
    'alignment': {'campaign': 'alignment', 'repetitions': 2, 'verification_repetitions': 1,
                  'flexure_elevations_deg': [], 'max_iterations': 1},
    'star-hop': {'campaign': 'star-hop', 'follow_times': False},
}
#: ...and the bag's own values of the fields that shape an element (frames averaged, drift track, move sizes, the
#: TASCU's alignment), so that each element is flown as the designed plan will fly it.
_ELEMENT_FIELDS = {
    'alignment': ('frames_per_position', 'drift_track_s', 'los_angle_deg', 'elxel_length_arcmin', 'timeout_s'),
    'star-hop': ('frames_per_position', 'timeout_s', 'tarf_from_gyrf'),
}
#: The star hop's library flight observes the bag's last two observations (back to back) before its elements: the
#: stars and elevations the designed plan's elements follow.
_STAR_HOP_LEAD_OBSERVATIONS = 2
#: --jobs' default per usable core. The flights are few (at most five) and about as long as each other: three on two
#: cores at once end together, sooner than two and then one (a thermal library's three steps: 48.0 and 47.9 s against
#: 57.4 and 57.1 s, alternated; the whole library, five flights, 63-66 s with 2, 3 or 5 at once).
_FLIGHTS_PER_CORE = 2
_DEFAULT_TARGET = 20.0
_DEFAULT_BUDGET_SHARE = 0.3


def add_design_arguments(parser: argparse.ArgumentParser) -> None:
    """Arguments of `sofia design`.

    Args:
        parser: the `sofia design` subparser.
    """
    parser.add_argument('source', nargs='?', help="a comparison's JSON (sofia compare --json) or a bag (with --model)")
    parser.add_argument('--model', metavar='M.yaml', help='the model compared (default: the JSON\'s model)')
    parser.add_argument('--between', metavar='A,B',
                        help="the competing set's two members; a member of several effects joins them with '+' "
                             '(e.g. hipo_fiducial_error,imager_boresight_offset+imager_rotation_of_field)')
    parser.add_argument('--set', type=integer(1, 1000, 'a competing set of the JSON'), metavar='N',
                        help="the JSON's competing set to design for (default 1, the first)")
    parser.add_argument('--budget-s', type=number(0.0, 1e6, 's', low_open=True), metavar='S',
                        help="longest addition of flight time (default 30 %% of the bag's flight)")
    parser.add_argument('--target', type=number(0.0, 1e9, 'delta-BIC', low_open=True),
                        metavar='DBIC', help='expected delta-BIC to reach both ways (default 20: twice the 10 that '
                                             'decides, as a margin)')
    parser.add_argument('--plan', metavar='PLAN.yaml', help="the plan the bag was flown with (default: its plan.yaml)")
    parser.add_argument('--plan-out', metavar='PLAN.yaml', help="write the bag's plan with the chosen elements added")
    parser.add_argument('--json', metavar='OUT', help='write the prediction as JSON (docs/design.md)')
    parser.add_argument('--check', metavar='NEW_BAG', help='the designed plan flown: refit the members on it and '
                                                          'on the old bag, print predicted against achieved')
    parser.add_argument('--prediction', metavar='DESIGN.json', help='--check: the design JSON it checks')
    parser.add_argument('--anchor-s', type=number(MIN_ANCHOR_S, MAX_ANCHOR_S, 's'),
                        help='seconds between attitude anchors, as compare (default 30; --check: the design\'s)')
    parser.add_argument('--quiet', action='store_true', help='no progress on stderr')
    parser.add_argument('--jobs', type=integer(1, 64, 'worker processes'),
                        help='library flights not in the cache yet (the temperature steps\' each a flight of its own) '
                             f'are flown in up to this many forked processes at once (default: {_FLIGHTS_PER_CORE} per '
                             f'usable core, {_FLIGHTS_PER_CORE * usable_cores()} here); the flights are the same with 1')


def _members(text: str) -> list:
    """--between A,B as two members, each a list of catalogue effects; ConfigError in one line otherwise."""
    from sofia_ros.compare.fit import free_parameters
    from sofia_ros.effects import NOISE_EFFECTS, get_effect

    members = [[name.strip() for name in part.split('+')] for part in text.split(',')]
    if len(members) != 2 or not all(all(member) for member in members):
        raise ConfigError(f'--between {text!r}: give two members, A,B (a member of several effects: X+Y)')
    for member in members:
        for name in member:
            get_effect(name)  # UnknownEffectError names the closest effects
            if name in NOISE_EFFECTS:
                raise ConfigError(f'--between: {name} is a random process, which sets the noise floor and moves no '
                                  'prediction; name an effect that does')
        if not free_parameters(member):
            raise ConfigError(f'--between: {"+".join(member)} has no numeric parameter to fit; name a fittable effect')
    if set(members[0]) & set(members[1]):
        raise ConfigError(f'--between {text!r}: the members share {sorted(set(members[0]) & set(members[1]))[0]}; '
                          'give two different explanations')
    return members


def _read_json(path: str, what: str) -> dict:
    from sofia_ros.input_files import read_text_capped

    text = read_text_capped(path, _MAX_JSON_BYTES, what.removeprefix('a '))
    try:
        document = json.loads(text)
    except json.JSONDecodeError as err:
        raise ConfigError(f'{path} is not JSON ({err.msg} at line {err.lineno}); give the file {what} wrote') from err
    if not isinstance(document, dict):
        raise ConfigError(f'{path} is not {what}: its top level is not an object')
    return document


def _source(args: argparse.Namespace) -> tuple:
    """(bag path, model path, members) from a comparison's JSON or a bag and the options."""
    if not args.source:
        raise ConfigError('give a comparison JSON or a bag (sofia design SOURCE), or --check NEW_BAG')
    source = Path(args.source)
    if source.is_dir():
        if not args.model:
            raise ConfigError(f'{source} is a bag: give the model it is compared with, --model M.yaml')
        if not args.between:
            raise ConfigError(f'{source} is a bag: name the competing set with --between A,B (or give the JSON of '
                              '`sofia compare --json`, whose competing sets it takes)')
        return source, args.model, _members(args.between)
    document = _read_json(args.source, 'a comparison (sofia compare --json)')
    if not isinstance(document.get('bag'), str) or 'competing' not in document:
        raise ConfigError(f'{args.source} is not the JSON of `sofia compare` on a bag (no bag or competing key)')
    search = document.get('search')
    if (not args.model and isinstance(search, dict) and search.get('written') is None
            and (search.get('added') or search.get('removed'))):
        # Its sets were found with the search's terms fitted: designed on the model given, they were another problem.
        raise ConfigError(f'{args.source} is the answer of a --search whose model ({document.get("model")} with the '
                          'search\'s changes) was not written; run the search with --write-model F.yaml, or give '
                          'the model with --model M.yaml')
    model = args.model or document.get('model')
    if model is not None and not isinstance(model, str):
        raise ConfigError(f'{args.source}: its model is not a file name; give the model with --model M.yaml')
    if args.between:
        return _named_here(args, document, model), model, _members(args.between)
    sets = document['competing'] or []
    if not isinstance(sets, list):
        raise ConfigError(f'{args.source}: its competing sets are not a list, as `sofia compare --json` writes them; '
                          'give --between A,B')
    if not sets:
        raise ConfigError(f'{args.source} states no competing set: the comparison already tells its candidates '
                          'apart; name one with --between A,B to design anyway')
    if args.set > len(sets):
        raise ConfigError(f'--set {args.set}: {args.source} states {len(sets)} competing set(s)')
    chosen = sets[args.set - 1]
    effects = chosen.get('effects') if isinstance(chosen, dict) else None
    if not isinstance(effects, list) or len(effects) < 2 or not all(isinstance(name, str) for name in effects):
        raise ConfigError(f'{args.source}: competing set {args.set} does not list two effects; give --between A,B')
    # A set of three or more: its first two, the strongest (--between names any other pair).
    return _named_here(args, document, model), model, _members(','.join(effects[:2]))


def _named_here(args: argparse.Namespace, document: dict, model: str | None) -> Path:
    """The JSON's bag, where it and the JSON's model (unless --model) are found from here: paths relative to the folder
    compare ran in, which the JSON does not record; ConfigError naming the JSON otherwise (it said only 'cannot read
    m.yaml')."""
    for what, named, fix in (('bag', document['bag'], 'give the bag: sofia design BAG --model M.yaml --between A,B'),
                             ('model', None if args.model else model, 'give --model M.yaml')):
        if named and not Path(named).is_absolute() and not Path(named).exists():
            raise ConfigError(f'{args.source} names its {what} {named} relative to the folder `sofia compare` ran in, '
                              f'and there is none here; run sofia design from that folder, or {fix}')
    return Path(document['bag'])


#: The result document each campaign writes into its bag (campaigns.alignment, campaigns.star_hop).
_RESULT_DOCUMENTS = {'alignment': 'calibration.yaml', 'star-hop': 'star_hop.yaml'}


def _bag_campaign(bag: Path) -> str | None:
    """The campaign a bag records, by the result document it holds (None: neither), so that a --plan of the other
    campaign is refused: given an alignment bag, a star-hop plan flew the star-hop library for it, at exit 0."""
    found = [campaign for campaign, name in _RESULT_DOCUMENTS.items() if (Path(bag) / name).is_file()]
    return found[0] if len(found) == 1 else None


def _thermal_control(bag: Path) -> dict | None:
    """The thermal control of the telescope the bag was flown on (its truth.yaml's scenario.thermal_control), or None:
    what a plan can command there, a property of the facility rather than of the errors being told apart."""
    from sofia_ros.config import load_effect_config

    truth = bag / 'truth.yaml'
    if not truth.is_file():  # an imported bag: no temperature element is offered
        return None
    return (load_effect_config(truth).scenario or {}).get('thermal_control')


def _library_elements(plan: Any, thermal_control: dict | None) -> tuple:
    """The element library for a bag flown with ``plan``: the alignment's (with its temperature steps where the
    telescope has ``thermal_control``), or the star hop's on its stars."""
    from sofia_ros.design.elements import ALIGNMENT_LIBRARY, star_hop_library, thermal_library

    # Only these two campaigns have plans (campaigns.plan_files.PLAN_TYPES).
    if plan.campaign == 'star-hop':
        return star_hop_library([star for star, _ in plan.observations])
    if thermal_control is None:
        return ALIGNMENT_LIBRARY
    return (*ALIGNMENT_LIBRARY, *thermal_library(thermal_control['min_c'], thermal_control['max_c'],
                                                 thermal_control['time_constant_s']))


def _library_document(elements: tuple, old_plan: Any) -> dict:
    """The library flight's plan: the campaign's shortest sequence, ``old_plan``'s element-shaping fields, the
    elements."""
    from sofia_ros.campaigns.plan_files import plan_document

    campaign = old_plan.campaign
    old = plan_document(old_plan)
    document = {**_LIBRARY_BASE[campaign], **{name: value for name, value in old.items()
                                               if name in _ELEMENT_FIELDS[campaign]}}
    if campaign == 'star-hop':
        document['observations'] = old['observations'][-_STAR_HOP_LEAD_OBSERVATIONS:]
    return {**document, 'elements': [step for element in elements for step in element.plan_elements]}


#: How long the change to the bag's last temperature before a library step holds, in time constants of the thermal
#: control: at most six (the temperature within 0.3 % of the change), and shorter where the bag ends sooner after the
#: library's short campaign, down to three (5 % of the change: the night's course is then within a few 0.1 C of it).
_RESET_TIME_CONSTANTS = (3.0, 6.0)
#: The change ends with a hold this long (s) at LOS 0: the Earth's turn walks the fine drive's LOS through the change's
#: long hold, and the next element's move to its star was refused beyond the fine drive's +-3 deg (a step at 25 deg
#: after a change at 55 deg: "fine drive LOS would reach -3.756 deg").
_RECENTRE_HOLD_S = 1.0
#: The bag's end is rounded to this (s) for the library's step flights: the bags of one plan and truth (seeds) that end
#: within it of each other share them.
_START_ROUNDING_S = 10.0


def _library_truth(thermal_control: dict | None, model_effects: dict) -> Any:
    """The library flight's truth: the nominal one, with the bag's thermal control if it has one, and the model's
    effects the nominal truth lacks at their values fitted on the bag (the telescope as the bag's fit knows it).

    The members' columns of a library element are added to the bag's, so both must be taken where the model puts the
    telescope: flown without the imagers' boresight offsets the bag's model fits (300" on the WFI), the HIPO set's
    rival (imager_rotation_of_field with the offsets fitted) was predicted to be told apart by 1900-2200 after one
    60 s hold, from geometry the bag and the library do not share; flown, it was 1-14.

    Args:
        thermal_control: the bag's scenario.thermal_control, or None.
        model_effects: {effect: {parameter: value}} of the model fitted on the bag (fitted_model_effects).

    Returns:
        The truth (EffectConfig); the nominal truth file's own text when it needs neither addition (the cache key of
        its flights).
    """
    import yaml

    from sofia_ros.campaigns.plan_files import plans_directory
    from sofia_ros.config import load_effect_config, parse_effect_config, safe_load_limited
    from sofia_ros.effects.empirical import is_empirical
    from sofia_ros.input_files import read_text_capped

    path = plans_directory().parent / 'truth' / 'nominal.yaml'
    nominal = load_effect_config(path)
    # An empirical term is a shape fitted to a residual, not an error a truth can hold.
    absent = {name: json_ready(params)
              for name, params in model_effects.items() if name not in nominal.effects and not is_empirical(name)}
    if thermal_control is None and not absent:
        return nominal
    document = safe_load_limited(read_text_capped(path, _MAX_JSON_BYTES, 'truth file'), str(path))
    document['effects'] = {**document['effects'], **absent}
    additions = [*(['the thermal control of the bag'] if thermal_control is not None else []),
                 *([f'the model\'s {", ".join(absent)} as fitted on the bag'] if absent else [])]
    if thermal_control is not None:
        document['scenario'] = {**(document.get('scenario') or {}), 'thermal_control': thermal_control}
    return parse_effect_config(yaml.safe_dump(document), f'{path} with {" and ".join(additions)}')


#: The bag's last temperature is rounded to this (C) for the library's step flights: the bags of one plan and truth
#: (seeds) end within it of each other and share them.
_RESET_ROUNDING_C = 0.1


def _elements_start_c(observations: Any) -> float:
    """The temperature a designed plan's elements start at: the bag's last (the plan is flown again before them),
    rounded to _RESET_ROUNDING_C."""
    last_c = float(observations.gyro.tick_temperature_c[-1])
    return round(round(last_c / _RESET_ROUNDING_C) * _RESET_ROUNDING_C, 3)


def _elements_start_s(observations: Any) -> float:
    """The sim time a designed plan's elements start at: the bag's last frame (the plan is flown again before them),
    rounded to _START_ROUNDING_S."""
    return round(float(observations.centroids.stamp_s.max()) / _START_ROUNDING_S) * _START_ROUNDING_S


def _step_lead(thermal_control: dict, start_c: float, start_s: float, campaign_end_s: float) -> tuple:
    """What a library step's flight flies between the short campaign (ending at ``campaign_end_s``) and the step: holds
    until about ``start_s``, where the designed plan's elements start, ending with a change to ``start_c``, the bag's
    last temperature, and the fine drive back at LOS 0.

    A temperature-dependent signature is the coefficient times the temperature's departure from the bag's, and one
    that follows time is told from it by the departure from the night's course: started from the night's 22.8 C where
    the designed plan starts from the bag's last 22.5 C, the library's departure at the slew after a 2 C step was 25 %
    short (issue 28's gyro set, seed 1); flown 1540 s later in the record than the designed plan, a third (its thermal
    set)."""
    from sofia_ros.design.elements import ELEMENT_OVERHEAD_S, Element, waiting_holds

    shortest, longest = (count * thermal_control['time_constant_s'] for count in _RESET_TIME_CONSTANTS)
    available_s = start_s - campaign_end_s - 2.0 * ELEMENT_OVERHEAD_S - _RECENTRE_HOLD_S
    held_s = float(round(min(max(available_s, shortest), longest)))
    reset = Element(f"to the bag's last {start_c:g} C", {'temperature': {'target_c': start_c, 'duration_s': held_s}},
                    ({'hold': {'duration_s': _RECENTRE_HOLD_S, 'los_deg': 0.0}},))
    return (*waiting_holds(available_s - held_s), reset)


def _campaign_end_s(bag: Path) -> float:
    """When a library flight's short campaign ended: its first element's start (sim s, calibration.yaml)."""
    import yaml

    from sofia_ros.design.geometry import element_windows
    from sofia_ros.input_files import read_text_capped

    calibration = yaml.safe_load(read_text_capped(bag / 'calibration.yaml', _MAX_JSON_BYTES, 'a calibration result'))
    starts = [entry['start_s'] for entry in (calibration or {}).get('elements') or [] if 'start_s' in entry]
    if not starts:
        raise BagError(f'the library flight {bag} records no element; delete it so that it is flown again')
    return float(min(starts))


@dataclass(frozen=True)
class _LibraryFlight:
    """A library flight: ``elements`` flown after the campaign's shortest sequence, a temperature step's after
    ``lead(end_s)`` too (waits to the bag's end time, the change to its last temperature), ``end_s`` being when that
    sequence ends; ``lead_key`` is what the lead is made of besides it, for the flight's key. ``read``: whether the
    design reads the flight's observations (the probe of the campaign's end is read for that end only)."""

    elements: tuple
    lead: Callable[[float], tuple] | None = None
    lead_key: dict | None = None
    read: bool = True

    def flown(self, campaign_end_s: float) -> tuple:
        """The elements it flies after a short campaign that ends at ``campaign_end_s``."""
        return self.elements if self.lead is None else (*self.lead(campaign_end_s), *self.elements)


def _library_flights(elements: tuple, old_plan: Any, truth: Any, thermal_control: dict | None, observations: Any,
                     progress: Progress, jobs: int, warm: Callable[[Path], Any] | None = None) -> list:
    """[(bag, the elements it flew)] of the library flights, each flown if not in the user's cache yet: the elements
    that command no temperature in one, on the night's course, where temperature and time move together as in the
    designed plan; each temperature step in one of its own, after a lead to the bag's end time and last temperature.

    A step is compared with a rival that follows the record's time (a creep, a drift), and what tells them apart is
    how far the step takes the temperature off the night's course at that time: flown after the other elements and
    the earlier steps (at 3383 s of the library's record where the designed plan flies it at 1843 s), the step's
    departure from the night's course was about a third smaller, and the prediction 2.3-2.6 times short (issue 28's
    thermal set). The lead needs the short campaign's end, which a probe flight (the short campaign and a hold of 1 s)
    finds beside the first flight: the steps then need not wait for the first flight's elements (_library_bags)."""
    from sofia_ros.design.elements import CAMPAIGN_END_PROBE, ELEMENT_OVERHEAD_S, WAIT_HOLD_S, is_thermal

    plain = _LibraryFlight(tuple(element for element in elements if not is_thermal(element)))
    if thermal_control is None or len(plain.elements) == len(elements):
        (bag,) = _library_bags([plain], old_plan, truth, progress, jobs, warm)
        return [(bag, plain.elements)]
    start_c, start_s = _elements_start_c(observations), _elements_start_s(observations)
    lead = functools.partial(_step_lead, thermal_control, start_c, start_s)
    # What the lead is made of besides the short campaign's end, which the rest of the key determines.
    lead_key = {'to_c': start_c, 'to_s': start_s, 'reset_time_constants': list(_RESET_TIME_CONSTANTS),
                'recentre_hold_s': _RECENTRE_HOLD_S, 'element_overhead_s': ELEMENT_OVERHEAD_S,
                'wait_hold_s': WAIT_HOLD_S}
    flights = [_LibraryFlight((CAMPAIGN_END_PROBE,), read=False), plain,
               *(_LibraryFlight((step,), lead, lead_key) for step in elements if is_thermal(step))]
    probe, *bags = _library_bags(flights, old_plan, truth, progress, jobs, warm)
    campaign_end_s = _campaign_end_s(probe)
    flown = [(bag, flight.flown(campaign_end_s)) for bag, flight in zip(bags, flights[1:])]
    for bag, elements in flown[1:]:
        _check_flown_as_planned(bag, elements, old_plan)
    return flown


def _check_flown_as_planned(bag: Path, elements: tuple, old_plan: Any) -> None:
    """BagError unless the library flight ``bag`` was flown with ``elements`` (its plan.yaml): a step's flight is kept
    under a key of its lead's inputs, not of the lead, and one that another version's waits made would put the step
    in another window of the flight."""
    from sofia_ros.campaigns.plan_files import read_plan

    if read_plan(bag) != _library_plan(elements, old_plan):
        raise BagError(f'the library flight {bag} was not flown with the plan this version makes for it: delete it '
                       'so that it is flown again')


def _library_bags(flights: list | tuple, old_plan: Any, truth: Any, progress: Progress, jobs: int,
                  warm: Callable[[Path], Any] | None = None) -> list[Path]:
    """The _LibraryFlights' bags in the user's cache, those not there yet flown (direct mode, ``truth``, seed 0) up to
    ``jobs`` at a time in forked processes (each flight is a campaign of its own, a core's work for 10-20 s), shaped
    by ``old_plan``'s fields as the designed plan will fly its elements. A flight with a lead starts once the first
    flight's bag is there: its short campaign ends where that one's did (the same sequence, truth and seed). A worker
    then reads its bag with ``warm`` (the observation cache's read): decoded there, side by side, the parent's read is
    the cache's."""
    bags = [_library_path(flight, old_plan, truth) for flight in flights]
    missing = [index for index, bag in enumerate(bags) if not (bag / 'summary.json').is_file()]
    if not missing:
        return bags
    at_once = min(jobs, len(missing))
    what = 'a library flight once' if len(missing) == 1 else f'{len(missing)} library flights once, {at_once} at a time'
    progress.phase(f'flying {what} (kept in {bags[0].parent})')
    bags[0].parent.mkdir(parents=True, exist_ok=True)
    # Those of a design killed outright (held_folders).
    remove_abandoned_folders(bags[0].parent, f'*{_FLYING_SUFFIX}')
    # Each flown in a folder of its own and renamed whole: a run that is interrupted leaves nothing, and of two runs
    # that fly it at once the first to finish is kept. The folders are made and removed here, not in the workers,
    # which Ctrl-C ends at once (forked_map).
    folders, locks = [], []
    parent = os.getpid()

    def fly(at: int) -> None:
        flight, bag = flights[missing[at]], bags[missing[at]]
        elements = flight.elements if flight.lead is None else flight.flown(_campaign_end_s(bags[0]))
        _fly_library_bag(elements, folders[at] / 'bag', old_plan, truth)
        try:
            (folders[at] / 'bag').rename(bag)
        except OSError:
            if not (bag / 'summary.json').is_file():
                raise
            # another design flew it meanwhile and put it there first: that one is kept
        if os.getpid() != parent and warm is not None and flight.read:
            warm(bag)

    after = {at: 0 for at, index in enumerate(missing) if flights[index].lead is not None and missing[0] == 0}
    try:
        for index in missing:
            folder, lock = held_folder(bags[index].parent, f'{bags[index].name}.', _FLYING_SUFFIX)
            folders.append(folder)
            locks.append(lock)
        forked_map(fly, range(len(missing)), jobs=at_once, after=after,
                   done=lambda count: progress.count('library flights flown', count, len(missing)))
    finally:
        for folder, lock in zip(folders, locks):
            release_folder(folder, lock)
    return bags


#: The suffix of a library flight's folder while it is flown (_library_bags).
_FLYING_SUFFIX = '.flying'


def _library_path(flight: _LibraryFlight, old_plan: Any, truth: Any) -> Path:
    """Where the library flight ``flight`` on ``truth`` is kept in the user's cache."""
    from sofia_ros.compare.cache import user_cache_home

    document = _library_document(flight.elements, old_plan)
    if flight.lead_key is not None:
        document['lead'] = flight.lead_key
    key = hashlib.sha256(json.dumps({**document, 'truth': truth.text}, sort_keys=True).encode()).hexdigest()[:16]
    return user_cache_home() / 'design' / f'{old_plan.campaign}-library-{key}'


def _library_plan(flight: tuple, old_plan: Any) -> Any:
    """The plan a library flight of ``flight``'s elements is flown with (_library_document's, parsed)."""
    from sofia_ros.campaigns.plan_files import plan_from_document

    return plan_from_document(_library_document(flight, old_plan), 'the design library', old_plan.campaign)


def _fly_library_bag(flight: tuple, bag: Path, old_plan: Any, truth: Any) -> None:
    """Fly ``flight``'s elements after the campaign's shortest sequence (direct mode, ``truth``, seed 0) into ``bag``."""
    from sofia_ros.campaigns.registry import campaign_named

    campaign_named(old_plan.campaign).run(truth, seed=0, bag_path=bag, plan=_library_plan(flight, old_plan),
                                          mode='direct')


def _flight_s(observations: Any) -> float:
    return float(observations.centroids.stamp_s.max() - observations.initial_time_s)


def _print_design(document: dict, out: TextIO) -> None:
    first, second = document['members']
    print(f'sofia design: {first} or {second} on {document["bag"]} (flight {document["flight_s"]:.0f} s, '
          f'budget {document["budget_s"]:.0f} s)', file=out)
    print(f'  model {document["model"]}; shared fitted terms: {len(document["shared"])}', file=out)
    for name, sizes in document['sizes'].items():
        sigma = document['sigma_before'][name]
        text = ', '.join(f'{label.split(".", 1)[1]} {value:.4g} +- {sigma[label]:.2g}'
                         for label, value in sizes.items())
        print(f'  {name}: fitted size {text}; delta-BIC on the bag {document["observed_delta_bic"][name]:.0f}',
              file=out)
    for name, assumed in document['assumed_sizes'].items():
        for label, size in assumed.items():
            print(f'  assuming {label} at its catalogue size {size["value"]:g} {size["unit"]} if {name} is true (the '
                  f'bag does not measure it: {size["bag_value"]:.3g} +- {size["bag_sigma"]:.2g})', file=out)
    before = document['before']
    print(f'  expected separation now: {_ways(before)}', file=out)
    print('elements (expected delta-BIC with the element added; per minute of flight)', file=out)
    heads = [f'if {name} true'[:24] for name in (first, second)]
    print(f'  {"element":52} {"flight":>7}  {heads[0]:>24}  {heads[1]:>24}', file=out)
    for entry in document['elements']:
        cells = [f'{entry["separation"][name]:9.1f} ({entry["separation_per_minute"][name]:+7.1f}/min)'
                 for name in document['members']]
        print(f'  {entry["name"]:52} {entry["flight_s"]:6.0f}s  {cells[0]:>24}  {cells[1]:>24}', file=out)
    for name in document['skipped']:
        print(f'  {name:52} skipped: not flown in the library flight (no star in reach; its summary.json says)',
              file=out)
    status = document['status']
    if status == 'already_separated':
        print(f'already separated: the bag tells them apart by delta-BIC >= {document["target_delta_bic"]:g} '
              'whichever is true; no plan is needed', file=out)
        return
    _print_reproduced(document, out)
    if status == 'inseparable':
        print('no plan: no element separates them further (the other direction, if any, is separated already)',
              file=out)
        return
    chosen = ', '.join(entry['name'] for entry in document['chosen'])
    print(f'{"designed" if status == "designed" else "best within the budget (target not reached)"}: {chosen} '
          f'({document["chosen_flight_s"]:.0f} s, {100 * document["flight_share"]:.0f} % of the flight)', file=out)
    print(f'  expected separation after: {_ways(document["predicted"])} (target {document["target_delta_bic"]:.0f})',
          file=out)
    if status == 'not_reached':
        whole = document['whole_library']
        print(f'  with every element of the library ({whole["flight_s"]:.0f} s): {_ways(whole["separation"])}; '
              'a direction that stays below the target is one these elements cannot separate (the other member '
              "reproduces that member's signature in their geometry)", file=out)
    for name in document['members']:
        # effect.parameter, an empirical effect's name holding dots of its own (poly3@61.76..921.2.p0_arcsec)
        shrink = [f'{label.rpartition(".")[2]} {before_sigma:.3g}->{document["sigma_after"][name][label]:.3g}'
                  for label, before_sigma in document['sigma_before'][name].items()
                  if label.rpartition('.')[0] in name.split('+')]
        print(f'  sigma with {name}: {", ".join(shrink)}', file=out)


def _print_reproduced(document: dict, out: TextIO) -> None:
    """The directions no element can separate: the rival reproduces the true member in the bag and every element."""
    whole = document['whole_library']
    for name in document['reproduced']:
        rival = next(member for member in document['members'] if member != name)
        print(f'if {name} is true, {rival} reproduces it in the bag and in every element (it leaves '
              f'{whole["signature_left"][name]:.2f} noise units of it with the whole library, '
              f'{whole["flight_s"]:.0f} s): no plan of these elements separates them that way; the delta-BIC stays '
              f'what their parameter counts make it, {document["before"][name]:.1f}', file=out)


def _ways(separation: dict) -> str:
    return ', '.join(f'if {name} true {value:.1f}' for name, value in separation.items())


def _design(args: argparse.Namespace, out: TextIO, progress: Progress) -> int:
    from sofia_ros.campaigns.plan_files import (plan_document, plan_from_document, read_plan, read_plan_file,
                                               write_plan_file)
    from sofia_ros.compare.cache import ObservationCache
    from sofia_ros.compare.observations import observation_cache, read_observations
    from sofia_ros.config import load_effect_config
    from sofia_ros.design.geometry import fit_model_on_bag, fitted_model_effects
    from sofia_ros.design.run import check_members, design_plan, flown_elements

    bag, model_path, members = _source(args)
    inputs = {'the bag': bag, 'the model': model_path, 'the comparison': args.source, 'the plan': args.plan}
    if args.plan_out:
        checked_output_file('--plan-out', args.plan_out, {**inputs, '--json': args.json})
    if args.json:
        checked_output_file('--json', args.json, inputs)
    if not model_path:
        raise ConfigError('give the model with --model M.yaml (the JSON names none)')
    model = load_effect_config(model_path)
    check_members(model, members)
    # An imported bag has no plan.yaml: the plan it was flown with is then given.
    old_plan = read_plan_file(args.plan, _bag_campaign(bag)) if args.plan else read_plan(bag)
    thermal_control = _thermal_control(bag)
    elements = _library_elements(old_plan, thermal_control)

    def read(path: Path, what: str, reporting: Progress = progress) -> Any:
        with observation_cache(ObservationCache(warn=lambda line: print(line, file=sys.stderr), progress=reporting)):
            reporting.phase(f'reading {what}')
            return read_observations(path)

    # The bag first: its end and last temperature are where the library's temperature steps start.
    observations = read(bag, 'the bag')
    progress.phase('fitting the model on the bag (the library flights fly the telescope it fits)')
    on_bag = fit_model_on_bag(observations, model, anchor_spacing_s=args.anchor_s)
    truth = _library_truth(thermal_control, fitted_model_effects(on_bag))
    flight_s = _flight_s(observations)
    budget_s = args.budget_s if args.budget_s is not None else _DEFAULT_BUDGET_SHARE * flight_s
    library, skipped = [], []

    def warm(path: Path) -> None:
        """A library flight read in the worker that flew it: its observations left in the cache."""
        read(path, 'a library flight', Progress.silent())

    for path, flight in _library_flights(elements, old_plan, truth, thermal_control, observations, progress,
                                         args.jobs, warm):
        flown = read(path, 'a library flight')
        windows, missed = flown_elements(flown.calibration_result, flight)
        # The waits and changes of temperature before a step are the flight's, not the library's.
        library.append((flown, [window for window in windows if window[0] in elements]))
        skipped += [name for name in missed if name in {element.name for element in elements}]
    progress.phase('linearizing the members on the bag and on the library flights')
    document = design_plan(observations, library, skipped, model, members, flight_s=flight_s, budget_s=budget_s,
                           target=args.target, anchor_spacing_s=args.anchor_s, on_bag=on_bag)
    _print_design(document, out)
    if document['status'] in {'designed', 'not_reached'} and args.plan_out:
        planned = plan_document(old_plan)
        planned['elements'] = [*planned.get('elements', []), *(step for entry in document['chosen']
                                                               for step in entry['element'])]
        write_plan_file(plan_from_document(planned, str(args.plan_out), old_plan.campaign), args.plan_out)
        document['plan'] = str(args.plan_out)
        print(f'plan: {args.plan_out} (fly it: sofia run {old_plan.campaign} --plan {args.plan_out} ...)', file=out)
    if args.json:
        write_text_atomically(args.json, json.dumps(json_ready(document), indent=2) + '\n')
    return 0


def _check(args: argparse.Namespace, out: TextIO, progress: Progress) -> int:
    from sofia_ros.compare.observations import read_observations
    from sofia_ros.config import load_effect_config
    from sofia_ros.design.check import member_fits

    if not args.prediction:
        raise ConfigError('--check NEW_BAG needs --prediction DESIGN.json (the JSON `sofia design --json` wrote)')
    ignored = [option for option, value in (('a SOURCE', args.source), ('--between', args.between),
                                            ('--plan', args.plan), ('--plan-out', args.plan_out),
                                            ('--set', args.set), ('--budget-s', args.budget_s),
                                            ('--target', args.target), ('--jobs', args.jobs))
               if value is not None]
    if ignored:
        raise ConfigError(f'--check takes the design (--prediction) and the bag flown with its plan; drop '
                          f'{", ".join(ignored)}')
    if args.json:
        checked_output_file('--json', args.json, {'the new bag': args.check, 'the design': args.prediction,
                                                  'the model': args.model})
    prediction = _read_json(args.prediction, 'a design (sofia design --json)')
    if not isinstance(prediction.get('members'), list) or not isinstance(prediction.get('predicted'), dict):
        raise ConfigError(f'{args.prediction} is not the JSON of `sofia design` (no members or predicted key)')
    # The members refitted at the spacing the prediction was made at (30 s in a design written before it was kept).
    designed_anchor_s = prediction.get('anchor_s', DEFAULT_ANCHOR_S)
    if args.anchor_s is not None and args.anchor_s != designed_anchor_s:
        raise ConfigError(f'--anchor-s {args.anchor_s:g} is not the {designed_anchor_s:g} s the design was made at; '
                          'drop --anchor-s (the check refits at the design\'s)')
    args.anchor_s = designed_anchor_s
    _check_flown_with_the_design(prediction, Path(args.check))
    model = load_effect_config(args.model or prediction['model'])
    members = _members(','.join(prediction['members']))
    achieved, start = {}, None
    for label, bag in (('before', prediction['bag']), ('after', args.check)):
        progress.phase(f'refitting both members on the {label} bag {bag}')
        fits = member_fits(read_observations(bag), model, members, anchor_spacing_s=args.anchor_s, start=start)
        # The designed flight is the old plan and more of the same telescope: each member's refit starts from its fit
        # on the old bag. From where it vanishes, the HIPO set's rival stopped 186 above its minimum on a star hop's
        # designed flight (issue 28, seed 2: BIC 1010.9 against 825.3 from the old bag's fit), and the separation
        # read 269.6 where the flight gives 84.0.
        start = {name: fit['values'] for name, fit in fits.items()}
        first, second = (fits['+'.join(member)]['bic'] for member in members)
        # Positive: the first member wins (its BIC is lower).
        achieved[label] = {'bag': str(bag), 'delta_bic': second - first,
                           'winner': '+'.join(members[0] if second > first else members[1]), 'fits': fits}
    first_name, second_name = prediction['members']
    print(f'sofia design --check: {first_name} or {second_name}', file=out)
    for label, entry in achieved.items():
        predicted = prediction['predicted' if label == 'after' else 'before'][entry['winner']]
        print(f'  {label:6} {entry["bag"]}: {entry["winner"]} wins by delta-BIC {abs(entry["delta_bic"]):.1f} '
              f'(predicted if it is true: {predicted:.1f})', file=out)
    if args.json:
        write_text_atomically(args.json, json.dumps(json_ready({'prediction': str(args.prediction), **achieved}),
                                                    indent=2) + '\n')
    return 0


def _check_flown_with_the_design(prediction: dict, new_bag: Path) -> None:
    """ConfigError unless ``new_bag`` was flown with the plan the design wrote, where both are there: any bag, the
    design's own too, was refitted and printed against the prediction at exit 0. A design that wrote no plan (the set
    already separated, or inseparable) is checked on its own bag."""
    from sofia_ros.campaigns.plan_files import read_plan, read_plan_file
    from sofia_ros.sim.sequence import PLAN_FILE_NAME

    designed = prediction.get('plan')
    if isinstance(designed, str) and Path(designed).is_file() and (new_bag / PLAN_FILE_NAME).is_file():
        if read_plan(new_bag) != read_plan_file(designed):
            raise ConfigError(f'--check {new_bag} was not flown with the designed plan {designed}; fly it with '
                              f'`sofia run CAMPAIGN --plan {designed} ...` and check that bag')


def run_design(args: argparse.Namespace, out: TextIO) -> int:
    """`sofia design`: the prediction and the plan, or with --check the achieved separation.

    Args:
        args: the parsed arguments of add_design_arguments.
        out: where the tables go.

    Returns:
        The exit code, 0 (faults raise a SofiaError: one line, exit 2; an unwritable output: OutputError).

    Raises:
        ConfigError: a bad source, member, model, plan or output.
        InvalidArgumentError: a budget below the shortest element.
    """
    progress = Progress.silent() if args.quiet else Progress(sys.stderr, prefix='sofia design')
    if args.check:
        return _check(args, out, progress)
    if args.prediction:
        raise ConfigError('--prediction goes with --check NEW_BAG')
    # Defaults here, not in the parser: --check refuses these options given, which it would ignore.
    args.set = 1 if args.set is None else args.set
    args.target = _DEFAULT_TARGET if args.target is None else args.target
    args.anchor_s = DEFAULT_ANCHOR_S if args.anchor_s is None else args.anchor_s
    args.jobs = _FLIGHTS_PER_CORE * usable_cores() if args.jobs is None else args.jobs
    return _design(args, out, progress)
