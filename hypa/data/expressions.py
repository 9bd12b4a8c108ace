"""Derived channels: a safe arithmetic expression over the columns and scalars of a file.

``beta: {expression: "arctan2(`vy(m/s)`, `vx(m/s)`)", unit: rad}`` or
``force: {expression: "gtau * vir", unit: N}``. An expression is parsed with :mod:`ast` and
may hold only numbers, names, ``+ - * / ** %``, unary signs and calls of the functions in
:data:`FUNCTIONS`; nothing is ever passed to ``eval``. A name is a column (or, in a MATLAB
file, a scalar variable) of the file, in the file's units; a column whose name is not a Python
identifier is written in backticks, as in pandas (```vx(m/s)```). The result is in the
channel's declared ``unit`` and converted to SI like a plain column.
"""

from __future__ import annotations

import ast
import difflib
import math
import operator
import re
from collections.abc import Callable, Mapping

import numpy as np

from hypa.data.errors import DataError

#: Functions an expression may call (numpy's, applied sample by sample).
FUNCTIONS: dict[str, Callable[..., np.ndarray]] = {
    name: getattr(np, name)
    for name in ("abs", "sqrt", "exp", "log", "log10", "sin", "cos", "tan", "arcsin", "arccos",
                 "arctan", "arctan2", "sinh", "cosh", "tanh", "hypot", "deg2rad", "rad2deg",
                 "sign", "minimum", "maximum", "clip", "square")
}
#: Constants an expression may use.
CONSTANTS: dict[str, float] = {"pi": math.pi, "e": math.e}

_BINARY = {ast.Add: operator.add, ast.Sub: operator.sub, ast.Mult: operator.mul,
           ast.Div: operator.truediv, ast.Pow: operator.pow, ast.Mod: operator.mod}
_UNARY = {ast.UAdd: operator.pos, ast.USub: operator.neg}
_QUOTED = re.compile(r"`([^`]*)`")


class Expression:
    """A parsed expression; :attr:`names` are the file names it reads (constants excluded).

    Raises :class:`DataError` naming the channel for a syntax error or a disallowed construct
    (attribute access, subscripts, comparisons, lambdas, keywords, unknown functions, ...).
    """

    def __init__(self, text: str, channel: str) -> None:
        self.text = str(text)
        self.channel = channel
        self._quoted: dict[str, str] = {}

        def placeholder(match: re.Match) -> str:
            key = f"__column_{len(self._quoted)}"
            self._quoted[key] = match.group(1)
            return key

        source = _QUOTED.sub(placeholder, self.text)
        try:
            tree = ast.parse(source.strip(), mode="eval")
        except SyntaxError as error:
            raise DataError(
                f"expression of channel {channel!r} is not valid: {self.text!r} ({error.msg}); "
                f"write a column that is not a Python name in backticks, e.g. `vx(m/s)`"
            ) from None
        self._tree = tree.body
        names: list[str] = []
        self._check(self._tree, names)
        self.names: tuple[str, ...] = tuple(dict.fromkeys(names))

    def _name(self, node: ast.Name) -> str:
        return self._quoted.get(node.id, node.id)

    def _check(self, node: ast.AST, names: list[str]) -> None:
        if isinstance(node, ast.Constant) and type(node.value) in (int, float):
            return
        if isinstance(node, ast.Name):
            if node.id not in CONSTANTS or node.id in self._quoted:
                names.append(self._name(node))
            return
        if isinstance(node, ast.BinOp) and type(node.op) in _BINARY:
            self._check(node.left, names)
            self._check(node.right, names)
            return
        if isinstance(node, ast.UnaryOp) and type(node.op) in _UNARY:
            self._check(node.operand, names)
            return
        if isinstance(node, ast.Call):
            if not isinstance(node.func, ast.Name) or node.func.id not in FUNCTIONS:
                called = ast.unparse(node.func)
                raise DataError(
                    f"expression of channel {self.channel!r} calls {called!r}, which is not "
                    f"allowed: {self.text!r}; functions: {', '.join(FUNCTIONS)}"
                )
            if node.keywords:
                raise DataError(
                    f"expression of channel {self.channel!r}: keyword arguments are not allowed "
                    f"({self.text!r})"
                )
            for argument in node.args:
                self._check(argument, names)
            return
        shown = ast.unparse(node) if hasattr(ast, "unparse") else type(node).__name__
        raise DataError(
            f"expression of channel {self.channel!r} holds {shown!r} ({type(node).__name__}), "
            f"which is not allowed: {self.text!r}; use numbers, file columns, + - * / ** % and "
            f"the functions {', '.join(FUNCTIONS)}"
        )

    def evaluate(self, values: Mapping[str, np.ndarray | float], where: str = "") -> np.ndarray:
        """The expression over ``values`` (file name -> array or scalar), as float64.

        A name not in ``values`` is a :class:`DataError` naming ``where`` (the file), the name
        and the closest match.
        """
        missing = [name for name in self.names if name not in values]
        if missing:
            name = missing[0]
            guess = difflib.get_close_matches(name, list(values), n=1, cutoff=0.5)
            if not guess:  # `vx` for a column `vx(m/s)`: a prefix is the likely intent
                guess = [v for v in values if v.startswith(name)][:1]
            hint = f" (did you mean `{guess[0]}`?)" if guess else ""
            raise DataError(
                f"{where}: expression of channel {self.channel!r} uses {name!r}, which the file "
                f"does not have{hint}: {self.text!r}; the file has: {', '.join(values)}"
            )
        try:
            with np.errstate(all="ignore"):  # a NaN or inf result is reported by the caller
                result = self._eval(self._tree, values)
        except (ArithmeticError, ValueError, TypeError) as error:
            raise DataError(f"{where}: expression of channel {self.channel!r} fails: {self.text!r} "
                            f"({error})") from None
        return np.asarray(result, dtype=np.float64)

    def _eval(self, node: ast.AST, values: Mapping[str, np.ndarray | float]):
        if isinstance(node, ast.Constant):
            return float(node.value)  # float, so ``9 ** 9 ** 9`` overflows instead of running on
        if isinstance(node, ast.Name):
            if node.id in CONSTANTS and node.id not in self._quoted:
                return CONSTANTS[node.id]
            return values[self._name(node)]
        if isinstance(node, ast.BinOp):
            left, right = self._eval(node.left, values), self._eval(node.right, values)
            return _BINARY[type(node.op)](left, right)
        if isinstance(node, ast.UnaryOp):
            return _UNARY[type(node.op)](self._eval(node.operand, values))
        assert isinstance(node, ast.Call) and isinstance(node.func, ast.Name)  # checked in _check
        return FUNCTIONS[node.func.id](*(self._eval(a, values) for a in node.args))

    def __repr__(self) -> str:
        return f"Expression({self.text!r})"
