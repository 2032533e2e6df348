"""Node-id templates: one drive description, several drives on one bus.

A vendor's DBC describes one drive, often with the node number inside the arbitration ID
(CANopen: ``0x180 + node`` for TPDO1; node-id float protocols: ``node << 5 | cmd``; J1939: the
source address in the low byte). The config's ``bus.node.id`` is an expression of ``id`` (a
message's ID as the DBC writes it) and ``node`` (a drive's number) giving that message's ID on
that drive. Only integers, the two names, ``+ - * // % << >> & | ^ ~`` and parentheses are
allowed: the expression is parsed, never executed as Python.

>>> frame_id("(id & ~0x7F) | node", 0x181, 2)
386
>>> frame_id("node << 5 | (id & 0x1F)", 0x009, 3)
105
"""

from __future__ import annotations

import ast
import operator
from collections.abc import Callable

from canfdi.core.settings import ConfigError

__all__ = ["MAX_EXTENDED_ID", "MAX_STANDARD_ID", "check_template", "frame_id"]

MAX_STANDARD_ID = 0x7FF
MAX_EXTENDED_ID = 0x1FFFFFFF

_BINARY: dict[type, Callable[[int, int], int]] = {
    ast.Add: operator.add, ast.Sub: operator.sub, ast.Mult: operator.mul,
    ast.FloorDiv: operator.floordiv, ast.Mod: operator.mod, ast.LShift: operator.lshift,
    ast.RShift: operator.rshift, ast.BitAnd: operator.and_, ast.BitOr: operator.or_,
    ast.BitXor: operator.xor,
}
_UNARY: dict[type, Callable[[int], int]] = {ast.Invert: operator.invert, ast.USub: operator.neg,
                                            ast.UAdd: operator.pos}
_NAMES = ("id", "node")


def _evaluate(node: ast.AST, names: dict[str, int]) -> int:
    if isinstance(node, ast.Expression):
        return _evaluate(node.body, names)
    if isinstance(node, ast.Constant) and isinstance(node.value, int) \
            and not isinstance(node.value, bool):
        return node.value
    if isinstance(node, ast.Name) and node.id in names:
        return names[node.id]
    if isinstance(node, ast.BinOp) and type(node.op) in _BINARY:
        return _BINARY[type(node.op)](_evaluate(node.left, names), _evaluate(node.right, names))
    if isinstance(node, ast.UnaryOp) and type(node.op) in _UNARY:
        return _UNARY[type(node.op)](_evaluate(node.operand, names))
    raise ValueError(f"{ast.unparse(node)!r} is not allowed (integers, id, node, "
                     "+ - * // % << >> & | ^ ~ and parentheses)")


def _parse(template: str) -> ast.Expression:
    return ast.parse(template.strip(), mode="eval")


def check_template(template: str, field: str) -> None:
    """Raise ConfigError(field) unless ``template`` is a valid expression of id and node."""
    try:
        tree = _parse(template)
        _evaluate(tree, dict.fromkeys(_NAMES, 1))
    except (SyntaxError, ValueError, ZeroDivisionError) as exc:
        detail = exc.msg if isinstance(exc, SyntaxError) else str(exc)
        raise ConfigError(field, f"not a node-id template ({detail}): {template!r}") from None


def frame_id(template: str | None, dbc_id: int, node: int | None) -> int:
    """The frame ID of the message of DBC ID ``dbc_id`` on drive ``node`` (the DBC's ID when
    there is no template or no node); ValueError when the result is no CAN ID."""
    if template is None or node is None:
        return dbc_id
    value = _evaluate(_parse(template), {"id": dbc_id, "node": node})
    if not 0 <= value <= MAX_EXTENDED_ID:
        raise ValueError(f"gives 0x{value:X} for id 0x{dbc_id:X}, node {node}: not a CAN ID")
    return value
