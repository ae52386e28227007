"""The ``sofia`` command (DESIGN.md section 6).

Exit codes: 0 success, 2 bad input (one line on stderr), 1 bug (traceback).
"""

from __future__ import annotations

import argparse
import json
import sys

from sofia_ros.errors import SofiaError

__all__ = ['main', 'build_parser']


def _print_effects(args):
    from sofia_ros.effects import CATALOGUE, catalogue_as_json

    if args.json:
        json.dump(catalogue_as_json(), sys.stdout, indent=2)
        sys.stdout.write('\n')
        return 0
    for spec in CATALOGUE.values():
        print(f'{spec.name}  [{spec.family}; thesis {spec.thesis}]')
        print(f'    {spec.description}')
        for param in spec.params:
            print(f'    - {param.name} = {param.default} {param.unit}: {param.description}')
    return 0


def _run_demo(args):
    from sofia_ros.demo import run_demo

    return run_demo(out=sys.stdout)


def build_parser():
    """The argument parser with one sub-command per verb."""
    parser = argparse.ArgumentParser(prog='sofia', description=__doc__.splitlines()[0])
    verbs = parser.add_subparsers(dest='verb', required=True, metavar='COMMAND')

    effects = verbs.add_parser('effects', help='list the catalogue of physical effects')
    effects.add_argument('--json', action='store_true', help='print the catalogue as JSON')
    effects.set_defaults(handler=_print_effects)

    demo = verbs.add_parser('demo', help='worked demonstration of the science core against the thesis tables')
    demo.set_defaults(handler=_run_demo)
    return parser


def main(argv=None):
    """Entry point of the ``sofia`` console script."""
    args = build_parser().parse_args(argv)
    try:
        return args.handler(args)
    except SofiaError as err:
        print(f'sofia: error: {err}', file=sys.stderr)
        return 2
    except BrokenPipeError:
        return 0


if __name__ == '__main__':
    sys.exit(main())
