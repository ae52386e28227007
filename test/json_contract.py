"""The typed contract of the `--json` outputs (docs/schemas/): validate a document a test has written.

A test that writes `sofia compare --json` or `sofia noise --json` can check it whole::

    from json_contract import load_json, validate_compare
    validate_compare(load_json(out))

Each violation is one line (where, what); all of them are raised together as one ContractViolation, an
AssertionError, so a broken contract reads as a failed test. JSON Schema cannot say "finite", so the
helpers also refuse NaN and infinities, which the tools write as null (output_files.json_ready).
Needs the `jsonschema` package (requirements-test.txt).
"""

import json
import math
from functools import cache
from pathlib import Path

from jsonschema import Draft202012Validator

SCHEMAS = Path(__file__).resolve().parents[1] / 'docs' / 'schemas'


class ContractViolation(AssertionError):
    """A document that breaks its schema: one line per violation."""


@cache
def _validator(name):
    schema = json.loads((SCHEMAS / f'{name}.schema.json').read_text())
    Draft202012Validator.check_schema(schema)
    return Draft202012Validator(schema)


def _non_finite(value, path='$'):
    """Where a float is NaN or infinite (a document parsed leniently, or built in memory)."""
    if isinstance(value, float) and not math.isfinite(value):
        yield f'{path}: {value!r} is not a finite number (write null)'
    elif isinstance(value, dict):
        for key, item in value.items():
            yield from _non_finite(item, f'{path}.{key}')
    elif isinstance(value, list):
        for index, item in enumerate(value):
            yield from _non_finite(item, f'{path}[{index}]')


def _validate(name, document):
    problems = [f'{error.json_path}: {error.message}' for error in _validator(name).iter_errors(document)]
    problems += list(_non_finite(document))
    if problems:
        raise ContractViolation(f'{len(problems)} violation(s) of docs/schemas/{name}.schema.json:\n'
                                + '\n'.join(sorted(problems)))


def validate_compare(document):
    """`sofia compare --json` of a bag or a measurement set (docs/schemas/compare.schema.json); the document."""
    _validate('compare', document)
    return document


def validate_noise(document):
    """`sofia noise --json` (docs/schemas/noise.schema.json); the document."""
    _validate('noise', document)
    return document


def _refuse_constant(token):
    raise ContractViolation(f'{token} is not JSON (RFC 8259 has no non-finite numbers; write null)')


def load_json(path):
    """A JSON file parsed strictly: the NaN and Infinity tokens Python's json would accept are refused."""
    return json.loads(Path(path).read_text(), parse_constant=_refuse_constant)
