"""`sofia perturb BAG OUT --observable OBS --shape EXPR [--unit UNIT]`: arguments and the summary line."""

from __future__ import annotations

from typing import TYPE_CHECKING

from sofia_ros.output_files import refuse_empty_paths, refuse_over_inputs
from sofia_ros.perturb.observables import OBSERVABLES
from sofia_ros.perturb.run import perturb_bag
from sofia_ros.perturb.shapes import FUNCTIONS
from sofia_ros.perturb.variables import CAMERA_SHAPE_VARIABLES

if TYPE_CHECKING:
    import argparse
    from typing import TextIO

__all__ = ['add_perturb_arguments', 'run_perturb']


def add_perturb_arguments(parser: argparse.ArgumentParser) -> None:
    """The arguments of `sofia perturb`."""
    parser.add_argument('bag', help='campaign bag directory to copy')
    parser.add_argument('out', help='new bag directory for the perturbed copy (must not exist)')
    parser.add_argument('--observable', required=True, metavar='OBS',
                        help=f'what to change: {", ".join(OBSERVABLES)}')
    parser.add_argument('--shape', required=True, metavar='EXPR',
                        help=f'numpy expression added to it per row, in {", ".join(CAMERA_SHAPE_VARIABLES)} '
                             f'(the last three: cameras only), constants pi, e and {", ".join(FUNCTIONS)}; '
                             "e.g. '2.0*(time_s > 600)'")
    parser.add_argument('--unit', help='unit of the shape: arcsec (default) or px for a camera axis, '
                                       'deg_per_h (default) or arcsec_per_s for a gyro axis')


def run_perturb(args: argparse.Namespace, out: TextIO) -> int:
    """Perturb the bag and print one summary line."""
    refuse_empty_paths(('BAG', args.bag), ('OUT', args.out))
    refuse_over_inputs('OUT', args.out, {'the bag': args.bag})
    result = perturb_bag(args.bag, args.out, args.observable, args.shape, unit=args.unit)
    out.write(f'perturbed {result.observable} of {args.bag} into {args.out}: {result.rows_changed} rows changed; '
              f'added {result.shape!r}: RMS {result.rms:.6g}, min {result.min:.6g}, max {result.max:.6g} '
              f'{result.unit}\n')
    return 0
