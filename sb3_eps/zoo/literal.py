"""A restricted parser for the Python literals of RL Zoo configs, e.g. ``"dict(net_arch=[64, 64], activation_fn=nn.Tanh)"``.

RL Zoo ``eval()``s such strings. Here they are parsed with :mod:`ast` and only these forms are accepted: numbers
(with a sign), strings, ``True`` / ``False`` / ``None``, lists, tuples (read as lists), ``{...}`` with string keys,
``dict(key=value, ...)`` with keyword arguments only, and the dotted names of an allow-list (activation functions
and optimizer classes), which come back as their canonical names (``"nn.Tanh"``). Nothing is evaluated: a call of
anything but ``dict``, an operator, an attribute of anything but an allowed name, a comprehension... is refused
with a :class:`~sb3_eps.zoo.errors.ConfigError` that shows the offending piece.
"""

from __future__ import annotations

import ast
from collections.abc import Mapping
from typing import Any

from sb3_eps.zoo.errors import ConfigError, allowed

#: The longest string the parser accepts (configs are short; this bounds the work on hostile input).
MAX_LITERAL_LENGTH = 4_000
#: The deepest nesting of containers the parser accepts.
MAX_DEPTH = 16


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
    return _Converter(text, names, where).convert(tree.body, 0)


class _Converter:
    """Walks an expression tree, accepting only the literal forms of the module docstring."""

    def __init__(self, text: str, names: Mapping[str, str], where: str) -> None:
        self.text = text
        self.names = names
        self.where = where

    def refuse(self, node: ast.AST, why: str) -> ConfigError:
        piece = ast.get_source_segment(self.text.strip(), node) or type(node).__name__
        return ConfigError(
            f"{self.where}: {piece!r} is not allowed ({why}); only numbers, strings, True/False/None, lists, "
            f"{{...}}, dict(key=value, ...) and the names {allowed(sorted(set(self.names.values())))} may appear"
        )

    def convert(self, node: ast.AST, depth: int) -> Any:
        if depth > MAX_DEPTH:
            raise self.refuse(node, f"nested deeper than {MAX_DEPTH} levels")
        if isinstance(node, ast.Constant):
            if isinstance(node.value, bool | int | float | str) or node.value is None:
                return node.value
            raise self.refuse(node, f"a {type(node.value).__name__} constant")
        if isinstance(node, ast.UnaryOp) and isinstance(node.op, ast.USub | ast.UAdd):
            operand = self.convert(node.operand, depth + 1)
            if isinstance(operand, bool) or not isinstance(operand, int | float):
                raise self.refuse(node, "a sign applies to numbers only")
            return -operand if isinstance(node.op, ast.USub) else operand
        if isinstance(node, ast.List | ast.Tuple):
            return [self.convert(element, depth + 1) for element in node.elts]
        if isinstance(node, ast.Dict):
            return self.convert_dict(node, depth)
        if isinstance(node, ast.Call):
            return self.convert_call(node, depth)
        if isinstance(node, ast.Name | ast.Attribute):
            return self.convert_name(node)
        raise self.refuse(node, f"a {type(node).__name__} expression")

    def convert_dict(self, node: ast.Dict, depth: int) -> dict[str, Any]:
        result: dict[str, Any] = {}
        for key, value in zip(node.keys, node.values, strict=True):
            if not (isinstance(key, ast.Constant) and isinstance(key.value, str)):
                raise self.refuse(key or node, "dictionary keys must be strings")
            result[key.value] = self.convert(value, depth + 1)
        return result

    def convert_call(self, node: ast.Call, depth: int) -> dict[str, Any]:
        if not (isinstance(node.func, ast.Name) and node.func.id == "dict"):
            raise self.refuse(node, "the only call allowed is dict(...)")
        if node.args:
            raise self.refuse(node, "dict(...) takes keyword arguments only")
        result: dict[str, Any] = {}
        for keyword in node.keywords:
            if keyword.arg is None:
                raise self.refuse(node, "dict(...) takes no **arguments")
            result[keyword.arg] = self.convert(keyword.value, depth + 1)
        return result

    def convert_name(self, node: ast.Name | ast.Attribute) -> str:
        parts: list[str] = []
        current: ast.AST = node
        while isinstance(current, ast.Attribute):
            parts.append(current.attr)
            current = current.value
        if not isinstance(current, ast.Name):
            raise self.refuse(node, "attributes are allowed on names only")
        parts.append(current.id)
        dotted = ".".join(reversed(parts))
        if dotted not in self.names:
            raise self.refuse(node, "an unknown name")
        return self.names[dotted]
