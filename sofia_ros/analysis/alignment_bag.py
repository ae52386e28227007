"""Repeat the calibration node's alignment fits offline from a recorded bag (3.3.2, 6.1)."""

from __future__ import annotations

from dataclasses import dataclass
from os import PathLike

import numpy as np
import yaml

from sofia_ros.bag import BagReader
from sofia_ros.calibration.maneuver_records import maneuver_from_record
from sofia_ros.calibration.solvers import AlignmentFit, fit_alignment
from sofia_ros.errors import BagError
from sofia_ros.sensors.imager_model import nominal_detector
from sofia_ros.topics import CALIBRATION_MANEUVERS

__all__ = ['OfflineFit', 'refit_alignments']


@dataclass(frozen=True)
class OfflineFit:
    """One fit the calibration node made, repeated from the bag's maneuver records."""

    purpose: str
    camera: str
    fit: AlignmentFit


def refit_alignments(bag_path: str | PathLike[str]) -> list[OfflineFit]:
    """Every alignment fit of a run, solved again from /calibration/maneuvers, in recording order.

    Args:
        bag_path: a bag recorded by an alignment campaign.

    Returns:
        One OfflineFit per maneuver record document, in recording order.

    Raises:
        BagError: the bag has no /calibration/maneuvers topic (or cannot be read).
    """
    with BagReader(bag_path) as bag:
        if CALIBRATION_MANEUVERS.name not in {topic.name for topic in bag.topics}:
            raise BagError(f'{bag_path} has no /calibration/maneuvers; record an alignment campaign first')
        documents = [yaml.safe_load(message.data) for _, _, message in bag.messages(CALIBRATION_MANEUVERS.name)]
    fits = []
    for document in documents:
        maneuvers = [maneuver_from_record(record) for record in document['maneuvers']]
        camera = document['camera']
        fit = fit_alignment(maneuvers, nominal_detector(camera), solve_for=tuple(document['solve_for']),
                            fit_drift=document['fit_drift'], initial_dcm=np.eye(3) if camera != 'hipo' else None)
        fits.append(OfflineFit(document['purpose'], camera, fit))
    return fits
