"""A safe numpy expression in named per-row variables: parsed with ``ast``, only whitelisted nodes run.

``2.0*(time_s > 600)``, ``0.5*sin(2*pi*time_s/300)``, ``where(elevation_deg > 40, 1, -1)``: numbers,
names, + - * / ** %, unary - and +, comparisons (True/False become 1/0) and calls of the functions in
FUNCTIONS with positional arguments. No attribute, subscript, keyword, lambda or anything else, so an
expression can neither reach Python's internals nor run for long (its length is capped).
"""

from __future__ import annotations

import ast
import operator
from typing import TYPE_CHECKING

import numpy as np

from sofia_ros.errors import PerturbationError

if TYPE_CHECKING:
    from collections.abc import Callable, Mapping

__all__ = ['ARITY', 'CONSTANTS', 'FUNCTIONS', 'MAX_EXPRESSION_CHARS', 'evaluate_shape', 'parse_shape', 'shape_names']

#: Longest expression accepted, in characters.
MAX_EXPRESSION_CHARS = 500

#: The functions an expression may call (numpy's, elementwise).
FUNCTIONS: Mapping[str, Callable[..., np.ndarray]] = {
    name: getattr(np, name) for name in (
        'sin', 'cos', 'tan', 'arcsin', 'arccos', 'arctan', 'arctan2', 'exp', 'log', 'log10', 'sqrt', 'abs',
        'sign', 'radians', 'degrees', 'minimum', 'maximum', 'where', 'clip', 'floor', 'heaviside',
    )
}
_TWO_ARGUMENTS = ('arctan2', 'minimum', 'maximum', 'heaviside')
#: How many positional arguments each function takes.
ARITY: Mapping[str, int] = {name: 3 if name in ('where', 'clip') else 2 if name in _TWO_ARGUMENTS else 1
                            for name in FUNCTIONS}
#: Names that are numbers in every expression.
CONSTANTS: Mapping[str, float] = {'pi': float(np.pi), 'e': float(np.e)}

_BINARY = {ast.Add: operator.add, ast.Sub: operator.sub, ast.Mult: operator.mul, ast.Div: operator.truediv,
           ast.Pow: operator.pow, ast.Mod: operator.mod}
_UNARY = {ast.USub: operator.neg, ast.UAdd: operator.pos}
_COMPARE = {ast.Lt: operator.lt, ast.LtE: operator.le, ast.Gt: operator.gt, ast.GtE: operator.ge,
            ast.Eq: operator.eq, ast.NotEq: operator.ne}


def parse_shape(expression: str, variables: tuple[str, ...]) -> ast.Expression:
    """Parse and check ``expression`` against the whitelist and the known ``variables``; PerturbationError if not."""
    if not isinstance(expression, str) or not expression.strip():
        raise PerturbationError('the shape is empty; give a numpy expression such as 2.0*(time_s > 600)')
    if len(expression) > MAX_EXPRESSION_CHARS:
        raise PerturbationError(f'the shape has {len(expression)} characters, more than {MAX_EXPRESSION_CHARS}; '
                                'shorten the expression')
    try:
        tree = ast.parse(expression.strip(), mode='eval')
    except SyntaxError as err:
        raise PerturbationError(f'the shape {expression!r} is not a valid expression ({err.msg} at column '
                                f'{err.offset}); write it like 2.0*(time_s > 600)') from err
    called = {id(node.func) for node in ast.walk(tree) if isinstance(node, ast.Call)}
    for node in ast.walk(tree):
        _check_node(node, expression, variables, called)
    return tree


def shape_names(tree: ast.Expression) -> set[str]:
    """Every name a shape from parse_shape mentions (variables, constants, functions)."""
    return {node.id for node in ast.walk(tree) if isinstance(node, ast.Name)}


def evaluate_shape(tree: ast.Expression, variables: Mapping[str, np.ndarray]) -> np.ndarray:
    """The value of a shape from parse_shape with ``variables`` bound (arrays of one length); comparisons give 0/1."""
    with np.errstate(all='ignore'):
        return np.asarray(_value(tree.body, variables), dtype=float)


def _check_node(node: ast.AST, expression: str, variables: tuple[str, ...], called: set[int]) -> None:
    """Raise PerturbationError unless ``node`` is an allowed construct naming known things."""
    if isinstance(node, ast.Name):
        if node.id in FUNCTIONS and id(node) not in called:
            raise PerturbationError(f'the shape {expression!r} names the function {node.id} without calling it; '
                                    f'write {node.id}(...)')
        if node.id not in variables and node.id not in CONSTANTS and node.id not in FUNCTIONS:
            raise PerturbationError(f'unknown variable {node.id!r} in the shape; known variables: '
                                    f'{", ".join(variables)} (constants pi, e)')
        return
    if isinstance(node, ast.Call):
        if not isinstance(node.func, ast.Name) or node.func.id not in FUNCTIONS:
            raise PerturbationError(f'the shape {expression!r} calls something other than the functions '
                                    f'{", ".join(FUNCTIONS)}; use only those')
        if node.keywords or any(isinstance(arg, ast.Starred) for arg in node.args):
            raise PerturbationError(f'the shape {expression!r} passes keyword or starred arguments; '
                                    'pass each argument by position')
        if len(node.args) != ARITY[node.func.id]:
            raise PerturbationError(f'{node.func.id}() takes {ARITY[node.func.id]} argument(s), the shape '
                                    f'{expression!r} gives it {len(node.args)}')
        return
    allowed = (ast.Expression, ast.Constant, ast.BinOp, ast.UnaryOp, ast.Compare, ast.Load,
               *_BINARY, *_UNARY, *_COMPARE)
    if not isinstance(node, allowed) or (isinstance(node, ast.Constant) and not _is_number(node.value)):
        raise PerturbationError(f'the shape {expression!r} uses {type(node).__name__}, which is not allowed; '
                                'use numbers, variables, + - * / ** %, comparisons and the listed functions')
    if isinstance(node, ast.Constant) and not _is_finite_float(node.value):
        raise PerturbationError(f'the shape {_shortened(expression)!r} holds the number {_shortened(str(node.value))}, '
                                f'beyond a float\'s range (+-{np.finfo(float).max:.3g}); write a smaller number')


def _is_number(value: object) -> bool:
    """True for an int or float literal (not a bool, complex, string or bytes)."""
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def _is_finite_float(value: float) -> bool:
    """True for a literal that is a finite float64 (400 digits overflow, 1e999 is already inf)."""
    try:
        return bool(np.isfinite(np.float64(value)))
    except OverflowError:
        return False


def _shortened(text: str, length: int = 40) -> str:
    """``text``, cut to ``length`` characters with an ellipsis: a 400-digit number does not fill the line."""
    return text if len(text) <= length else f'{text[:length]}...'


def _value(node: ast.AST, variables: Mapping[str, np.ndarray]) -> np.ndarray | np.float64:
    """Evaluate a checked node; literals become float64 so that ``10**10**10`` overflows to inf at once."""
    if isinstance(node, ast.Constant):
        return np.float64(node.value)
    if isinstance(node, ast.Name):
        return np.float64(CONSTANTS[node.id]) if node.id in CONSTANTS else variables[node.id]
    if isinstance(node, ast.BinOp):
        return _BINARY[type(node.op)](_value(node.left, variables), _value(node.right, variables))
    if isinstance(node, ast.UnaryOp):
        return _UNARY[type(node.op)](_value(node.operand, variables))
    if isinstance(node, ast.Compare):
        left, result = _value(node.left, variables), np.float64(1.0)
        for op, comparator in zip(node.ops, node.comparators):
            right = _value(comparator, variables)
            result = result * _COMPARE[type(op)](left, right)
            left = right
        return result
    call = node
    return FUNCTIONS[call.func.id](*(_value(arg, variables) for arg in call.args))
