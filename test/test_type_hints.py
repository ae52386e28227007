"""The typed contract of the offline packages (issue 26): every public function and method annotated and
documented with Google-style ``Args:`` / ``Returns:`` (and ``Raises:`` where it raises a project error).

Public: a name without a leading underscore, defined in the module (not imported), at module level or
in a public class of the module. ``Returns:`` is not needed for ``-> None`` nor for a property (documented
as an attribute), ``Args:`` not for a function without parameters besides self/cls.
"""

from __future__ import annotations

import ast
import dataclasses
import importlib
import inspect
import pkgutil
import textwrap
import typing
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np
import pytest

from sofia_ros import errors
from json_contract import shape_gaps

#: The packages held to the contract. Modules of another owner still under way are excluded by name.
COVERED_PACKAGES = ('sofia_ros.noise', 'sofia_ros.analysis', 'sofia_ros.effects', 'sofia_ros.measurements',
                    'sofia_ros.compare')
EXCLUDED_MODULES = frozenset({

})

#: The project's own exceptions: raising one directly calls for a ``Raises:`` section.
PROJECT_ERRORS = frozenset(name for name, value in vars(errors).items()
                           if isinstance(value, type) and issubclass(value, errors.SofiaError))


def _modules(package_name: str) -> list[str]:
    """The modules of a package (the package itself included), less the excluded ones."""
    package = importlib.import_module(package_name)
    names = [package_name] + [f'{package_name}.{info.name}' for info in pkgutil.iter_modules(package.__path__)]
    return [name for name in names if name not in EXCLUDED_MODULES]


def _public_callables(module_name: str) -> Iterator[tuple[str, Callable, bool]]:
    """(qualified name, function, is_property) of each public function and method defined in the module."""
    module = importlib.import_module(module_name)
    for name, value in vars(module).items():
        if name.startswith('_') or getattr(value, '__module__', None) != module_name:
            continue
        if inspect.isfunction(value):
            yield f'{module_name}.{name}', value, False
        elif inspect.isclass(value) and not typing.is_typeddict(value):
            yield from _public_methods(module_name, value)


def _public_methods(module_name: str, cls: type) -> Iterator[tuple[str, Callable, bool]]:
    """The public methods and properties a class defines itself (not inherited, not generated)."""
    for name, member in vars(cls).items():
        if name.startswith('_'):
            continue
        if isinstance(member, property) and member.fget is not None:
            function, is_property = member.fget, True
        elif isinstance(member, (staticmethod, classmethod)):
            function, is_property = member.__func__, False
        elif inspect.isfunction(member):
            function, is_property = member, False
        else:
            continue
        if function.__qualname__.startswith(f'{cls.__qualname__}.'):
            yield f'{module_name}.{cls.__qualname__}.{name}', function, is_property


def _documented_parameters(function: Callable) -> list[str]:
    """The parameters an ``Args:`` section must describe: all but self/cls."""
    parameters = list(inspect.signature(function).parameters)
    if parameters and parameters[0] in ('self', 'cls'):
        parameters = parameters[1:]
    return parameters


def _directly_raised_project_errors(function: Callable) -> set[str]:
    """Project exceptions raised by name in the function's own body (nested functions aside)."""
    try:
        tree = ast.parse(textwrap.dedent(inspect.getsource(function)))
    except (OSError, TypeError, SyntaxError):
        return set()
    raised = set()
    nodes = list(ast.iter_child_nodes(tree.body[0]))
    while nodes:
        node = nodes.pop()
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda, ast.ClassDef)):
            continue
        if isinstance(node, ast.Raise) and node.exc is not None:
            target = node.exc.func if isinstance(node.exc, ast.Call) else node.exc
            name = target.id if isinstance(target, ast.Name) else getattr(target, 'attr', None)
            if name in PROJECT_ERRORS:
                raised.add(name)
        nodes.extend(ast.iter_child_nodes(node))
    return raised


def contract_gaps(qualified_name: str, function: Callable, is_property: bool) -> list[str]:
    """What a public function or method lacks: annotations and docstring sections, one string each."""
    gaps = []
    signature = inspect.signature(function)
    parameters = _documented_parameters(function)
    unannotated = [name for name in parameters if signature.parameters[name].annotation is inspect.Parameter.empty]
    if unannotated:
        gaps.append(f'{qualified_name}: parameters without annotation: {", ".join(unannotated)}')
    if signature.return_annotation is inspect.Signature.empty:
        gaps.append(f'{qualified_name}: no return annotation')
    docstring = inspect.getdoc(function) or ''
    if not docstring:
        gaps.append(f'{qualified_name}: no docstring')
        return gaps
    if parameters and not is_property:
        if '\nArgs:\n' not in docstring:
            gaps.append(f'{qualified_name}: no Args: section')
        else:
            missing = [name for name in parameters
                       if not any(line.strip().startswith((f'{name}:', f'{name} (', f'*{name}:', f'**{name}:'))
                                  for line in docstring.split('\nArgs:\n', 1)[1].splitlines())]
            if missing:
                gaps.append(f'{qualified_name}: Args: does not describe {", ".join(missing)}')
    returns_none = signature.return_annotation in (None, 'None')
    if not returns_none and not is_property and '\nReturns:\n' not in docstring and '\nYields:\n' not in docstring:
        gaps.append(f'{qualified_name}: no Returns: section')
    raised = _directly_raised_project_errors(function)
    if raised and '\nRaises:\n' not in docstring:
        gaps.append(f'{qualified_name}: raises {", ".join(sorted(raised))} without a Raises: section')
    return gaps


def _object_typed_fields(module_name: str) -> Iterator[str]:
    """Dataclass fields of the module annotated ``object`` (the contract must name the real type)."""
    module = importlib.import_module(module_name)
    for name, value in vars(module).items():
        if inspect.isclass(value) and dataclasses.is_dataclass(value) and value.__module__ == module_name:
            for field in dataclasses.fields(value):
                if field.type is object or 'object' in str(field.type).replace(' ', '').split('|'):
                    yield f'{module_name}.{name}.{field.name}: typed object'


@pytest.mark.parametrize('package_name', COVERED_PACKAGES)
def test_public_functions_are_annotated_and_documented(package_name):
    gaps = [gap for module_name in _modules(package_name)
            for qualified_name, function, is_property in _public_callables(module_name)
            for gap in contract_gaps(qualified_name, function, is_property)]
    assert not gaps, f'{len(gaps)} gaps in the typed contract:\n' + '\n'.join(gaps)


@pytest.mark.parametrize('package_name', COVERED_PACKAGES)
def test_dataclass_fields_name_their_types(package_name):
    gaps = [gap for module_name in _modules(package_name) for gap in _object_typed_fields(module_name)]
    assert not gaps, '\n'.join(gaps)


@pytest.mark.parametrize('package_name', COVERED_PACKAGES)
def test_star_import_works(package_name):
    namespace: dict = {}
    exec(f'from {package_name} import *', namespace)  # noqa: S102 (the import is the test)
    package = importlib.import_module(package_name)
    assert set(getattr(package, '__all__', ())) <= set(namespace)


def _sample(x: int, y: int = 0) -> int:
    """A sample: documented.

    Args:
        x: the first.
        y: the second.

    Returns:
        Their sum.
    """
    return x + y


def _undocumented(x, y):
    """A sample without sections."""
    if x:
        raise errors.ConfigError('x')
    raise ConfigErrorLike('y')


class ConfigErrorLike(Exception):
    """Not a project error."""


def test_checker_accepts_a_complete_function_and_names_each_gap():
    assert contract_gaps('sample', _sample, False) == []
    gaps = contract_gaps('undocumented', _undocumented, False)
    assert gaps == ['undocumented: parameters without annotation: x, y', 'undocumented: no return annotation',
                    'undocumented: no Args: section', 'undocumented: no Returns: section',
                    'undocumented: raises ConfigError without a Raises: section']


def test_the_noise_document_has_the_keys_of_its_typed_dicts():
    # A short decimated record with a line the model lacks: the optional keys (a decimated ARW, a
    # candidate's source) appear too. About a second.
    from sofia_ros.config import parse_effect_config
    from sofia_ros.noise.run import NoiseDocument, NoiseRecord, analyze_record

    rng = np.random.default_rng(7)
    time_s = np.arange(2**15)[:, np.newaxis] / 400.0
    rates = 0.5 * rng.standard_normal((2**15, 3)) + 20.0 * np.sin(2.0 * np.pi * 30.0 * time_s) + [9.97, -11.26, 0.01]
    case = {'case': 'generated', 'description': 'generated', 'latitude_deg': 34.9, 'heading_deg': 324.0,
            'elevation_deg': 40.1}
    model = parse_effect_config('effects:\n  gyro_noise: {}\n')
    document = analyze_record(NoiseRecord(Path('generated'), rates, case, {'main_oil_pump': 'on'}), model=model,
                              decimate=2).document
    assert any('source' in candidate for candidate in document['candidates'])
    assert 'arw_sampled_arcsec_per_sqrt_s' in document['axes']['el']
    assert shape_gaps(document, NoiseDocument, 'document') == []


def test_the_centroid_drift_and_catalogue_have_the_keys_of_their_typed_dicts():
    from sofia_ros.analysis.centroid_drift import CentroidDrift, fit_centroid_drift
    from sofia_ros.effects import CatalogueEntry, catalogue_as_json

    time_s = np.arange(60.0) * 10.0
    drift = fit_centroid_drift(time_s, 0.01 * time_s, 0.02 * time_s + 2.0 * np.sin(2.0 * np.pi * time_s / 300.0))
    assert drift['row']['sinusoid'] is not None
    assert shape_gaps(drift, CentroidDrift, 'drift') == []
    assert shape_gaps(catalogue_as_json(), list[CatalogueEntry], 'catalogue') == []


def test_the_shape_check_names_a_missing_and_an_unknown_key():
    from sofia_ros.noise.earth_rate import AbsoluteRates

    assert shape_gaps({'measured': 1.0, 'extra': 2.0}, AbsoluteRates, 'rates') == [
        "rates: key 'theoretical' missing", "rates: key 'extra' not in AbsoluteRates"]
