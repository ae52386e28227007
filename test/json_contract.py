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
import typing
from functools import cache
from pathlib import Path

from jsonschema import Draft202012Validator

from sofia_ros.compare.records import CandidateEntry, ConsistencyFinding, LedgerRow, Verdict

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


#: The typed records of a compare document (sofia_ros.compare.records) by key.
COMPARE_RECORDS = {'candidates': list[CandidateEntry], 'ledger': list[LedgerRow], 'verdict': Verdict,
                   'consistency': list[ConsistencyFinding]}


def validate_compare(document):
    """`sofia compare --json` of a bag or a measurement set (docs/schemas/compare.schema.json), its records also
    against their TypedDicts (compare.records); the document."""
    _validate('compare', document)
    gaps = [gap for key, hint in COMPARE_RECORDS.items() if key in document
            for gap in shape_gaps(document[key], hint, key)]
    if gaps:
        raise ContractViolation(f'{len(gaps)} key(s) outside sofia_ros.compare.records:\n' + '\n'.join(gaps))
    return document


def shape_gaps(value: object, hint: object, where: str) -> list[str]:
    """Where a value's dict keys differ from the TypedDicts its hint names (recursively through lists, dicts, |)."""
    if typing.is_typeddict(hint):
        if not isinstance(value, dict):
            return [f'{where}: {type(value).__name__}, not a {hint.__name__}']
        gaps = [f'{where}: key {key!r} missing' for key in sorted(hint.__required_keys__ - set(value))]
        gaps += [f'{where}: key {key!r} not in {hint.__name__}'
                 for key in sorted(set(value) - hint.__required_keys__ - hint.__optional_keys__)]
        hints = typing.get_type_hints(hint)
        for key in set(value) & set(hints):
            gaps += shape_gaps(value[key], hints[key], f'{where}.{key}')
        return gaps
    origin, arguments = typing.get_origin(hint), typing.get_args(hint)
    if origin is list and isinstance(value, list):
        return [gap for index, item in enumerate(value) for gap in shape_gaps(item, arguments[0], f'{where}[{index}]')]
    if origin is dict and isinstance(value, dict):
        return [gap for key, item in value.items() for gap in shape_gaps(item, arguments[1], f'{where}[{key!r}]')]
    if arguments and origin not in (list, dict, tuple):  # a union: the TypedDict member, unless the value is None
        members = [member for member in arguments if typing.is_typeddict(member)]
        if members and value is not None:
            return shape_gaps(value, members[0], where)
    return []


def validate_noise(document):
    """`sofia noise --json` (docs/schemas/noise.schema.json); the document."""
    _validate('noise', document)
    return document


def _refuse_constant(token):
    raise ContractViolation(f'{token} is not JSON (RFC 8259 has no non-finite numbers; write null)')


def load_json(path):
    """A JSON file parsed strictly: the NaN and Infinity tokens Python's json would accept are refused."""
    return json.loads(Path(path).read_text(), parse_constant=_refuse_constant)
