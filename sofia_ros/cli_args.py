"""Command-line numbers checked at parse time: finite, in range, with the unit in the message.

argparse turns the ArgumentTypeError into one line naming the option (``sofia: error: argument
--hold-s: ...``) and exit code 2, before anything is read or written.
"""

from __future__ import annotations

import argparse
import math

__all__ = ['OneLineParser', 'number', 'integer']


class OneLineParser(argparse.ArgumentParser):
    """An ArgumentParser whose errors are one line on stderr (no usage block), exit code 2."""

    def error(self, message):
        """Print ``prog: error: message`` and exit 2."""
        self.exit(2, f'{self.prog}: error: {message}; see {self.prog} --help\n')


def number(low, high, unit, *, low_open=False):
    """A float type for argparse: finite, ``low <= x <= high`` (``low < x`` when ``low_open``)."""
    opening = '(' if low_open else '['

    def parse(text):
        try:
            value = float(text)
        except ValueError as err:
            raise argparse.ArgumentTypeError(f'expected a number of {unit}, got {text!r}') from err
        inside = (value > low if low_open else value >= low) and value <= high
        if not math.isfinite(value) or not inside:
            raise argparse.ArgumentTypeError(f'must be a finite number in {opening}{low:g}, {high:g}] {unit}, '
                                             f'got {text}')
        return value

    parse.__name__ = 'number'
    return parse


def integer(low, high, what):
    """An int type for argparse within ``[low, high]``."""

    def parse(text):
        try:
            value = int(text)
        except ValueError as err:
            raise argparse.ArgumentTypeError(f'expected a whole number ({what}), got {text!r}') from err
        if not low <= value <= high:
            raise argparse.ArgumentTypeError(f'must be a whole number in [{low}, {high}] ({what}), got {value}')
        return value

    parse.__name__ = 'integer'
    return parse
