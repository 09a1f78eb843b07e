"""A restricted parser for the Python literals of RL Zoo configs, e.g. ``"dict(net_arch=[64, 64], activation_fn=nn.Tanh)"``.

RL Zoo ``eval()``s such strings. Here they are parsed with :mod:`ast`: ``dict(key=value, ...)`` becomes a ``{...}``,
tuples become lists, and the dotted names of an allow-list (activation functions and optimizer classes) become
their canonical names (``"nn.Tanh"``); what remains goes to :func:`ast.literal_eval` and may hold only numbers (with
a sign), strings, ``True`` / ``False`` / ``None``, lists and ``{...}``. Nothing is evaluated: a call of anything but
``dict``, an operator, an attribute of anything but an allowed name, a comprehension... is refused with a
:class:`~sb3_eps.zoo.errors.ConfigError` that shows the offending piece.
"""

from __future__ import annotations

import ast
from collections.abc import Mapping
from typing import Any

from sb3_eps.zoo.errors import ConfigError, allowed

#: The longest string the parser accepts (configs are short; this bounds the work on hostile input).
MAX_LITERAL_LENGTH = 4_000
#: The nodes :func:`ast.literal_eval` receives (after the rewriting of :class:`_Rewriter`).
_LITERAL_NODES = (ast.Constant, ast.List, ast.Dict, ast.UnaryOp, ast.USub, ast.UAdd, ast.Load)


def parse_literal(text: str, names: Mapping[str, str], where: str) -> Any:
    """Parse ``text`` as a restricted Python literal.

    :param text: the expression, e.g. ``"dict(net_arch=[64], activation_fn=nn.ReLU)"``
    :param names: allowed dotted names (every accepted spelling) -> canonical name
    :param where: what the text is, for error messages (``"file.yml: entry 'X': policy_kwargs"``)
    :return: plain Python data: dict, list, str, int, float, bool, None; allowed names as canonical strings
    :raises ConfigError: for anything that is not such a literal
    """
    if len(text) > MAX_LITERAL_LENGTH:
        raise ConfigError(f"{where}: the expression is longer than {MAX_LITERAL_LENGTH} characters")
    try:
        tree = ast.parse(text.strip(), mode="eval")
    except SyntaxError as error:
        raise ConfigError(f"{where}: {text!r} is not a valid literal ({error.msg})") from None
    rewriter = _Rewriter(text.strip(), names, where)
    body = rewriter.visit(tree.body)
    try:
        return ast.literal_eval(body)
    except ValueError:  # a sign on a string, a key spread with **...
        raise rewriter.refuse(tree.body, "not a literal") from None


class _Rewriter(ast.NodeTransformer):
    """Rewrites ``dict(...)`` calls, tuples and allowed names into literal nodes; refuses every other node."""

    def __init__(self, text: str, names: Mapping[str, str], where: str) -> None:
        self.text = text
        self.names = names
        self.where = where

    def refuse(self, node: ast.AST, why: str) -> ConfigError:
        piece = ast.get_source_segment(self.text, node) or type(node).__name__
        return ConfigError(
            f"{self.where}: {piece!r} is not allowed ({why}); only numbers, strings, True/False/None, lists, "
            f"{{...}}, dict(key=value, ...) and the names {allowed(sorted(set(self.names.values())))} may appear"
        )

    def generic_visit(self, node: ast.AST) -> ast.AST:
        constant = isinstance(node, ast.Constant) and not isinstance(node.value, bool | int | float | str | type(None))
        if constant or not isinstance(node, _LITERAL_NODES):
            raise self.refuse(node, f"a {type(node.value).__name__} constant" if constant else f"a {type(node).__name__}")  # type: ignore[attr-defined]
        return super().generic_visit(node)

    def visit_Call(self, node: ast.Call) -> ast.Dict:
        is_dict = isinstance(node.func, ast.Name) and node.func.id == "dict"
        if not is_dict or node.args or any(keyword.arg is None for keyword in node.keywords):
            raise self.refuse(node, "the only call allowed is dict(key=value, ...)")
        values = [self.visit(keyword.value) for keyword in node.keywords]
        return ast.Dict([ast.Constant(keyword.arg) for keyword in node.keywords], values)

    def visit_Tuple(self, node: ast.Tuple) -> ast.List:
        return ast.List([self.visit(element) for element in node.elts], ast.Load())

    def visit_Name(self, node: ast.Name | ast.Attribute) -> ast.Constant:
        dotted = ast.unparse(node)
        if dotted not in self.names:
            raise self.refuse(node, "an unknown name")
        return ast.Constant(self.names[dotted])

    visit_Attribute = visit_Name
