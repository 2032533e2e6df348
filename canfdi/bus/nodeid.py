"""Node-id templates: one drive description, several drives on one bus.

A vendor's DBC describes one drive, often with the node number inside the arbitration ID
(CANopen: ``0x180 + node`` for TPDO1; node-id float protocols: ``node << 5 | cmd``; J1939: the
source address in the low byte). The config's ``bus.node.id`` is an expression of ``id`` (a
message's ID as the DBC writes it) and ``node`` (a drive's number) giving that message's ID on
that drive. Only integers, the two names, ``+ - * // % << >> & | ^ ~`` and parentheses are
allowed: the expression is parsed, never executed as Python. It is bounded before anything
is computed: at most `MAX_TEMPLATE_LENGTH` characters and `MAX_TEMPLATE_DEPTH` levels of
nesting, shifts by at most 64 bits, every intermediate value within 2^64; and it is evaluated
at load time for every drive's node (and for every DBC ID when the bus map is built), so a
division by zero or an ID out of range is a config error, not a crash when a drive starts.

>>> frame_id("(id & ~0x7F) | node", 0x181, 2)
386
>>> frame_id("node << 5 | (id & 0x1F)", 0x009, 3)
105
"""

from __future__ import annotations

import ast
import operator
from collections.abc import Callable

from canfdi.core.settings import ConfigError, brief

__all__ = ["MAX_EXTENDED_ID", "MAX_STANDARD_ID", "MAX_TEMPLATE_DEPTH", "MAX_TEMPLATE_LENGTH",
           "check_template", "frame_id"]

MAX_STANDARD_ID = 0x7FF
MAX_EXTENDED_ID = 0x1FFFFFFF
MAX_TEMPLATE_LENGTH = 200
"""Characters in a template (a vendor's rule is a handful of operators)."""
MAX_TEMPLATE_DEPTH = 12
"""Levels of nesting of a template's expression tree."""
_MAX_SHIFT = 64
_MAX_VALUE = 1 << 64

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
    value = _evaluate_node(node, names)
    if abs(value) >= _MAX_VALUE:
        raise ValueError(f"{ast.unparse(node)!r} reaches {value.bit_length()} bits (at most 64)")
    return value


def _evaluate_node(node: ast.AST, names: dict[str, int]) -> int:
    if isinstance(node, ast.Expression):
        return _evaluate(node.body, names)
    if isinstance(node, ast.Constant) and isinstance(node.value, int) \
            and not isinstance(node.value, bool):
        return node.value
    if isinstance(node, ast.Name) and node.id in names:
        return names[node.id]
    if isinstance(node, ast.BinOp) and type(node.op) in _BINARY:
        left, right = _evaluate(node.left, names), _evaluate(node.right, names)
        if isinstance(node.op, ast.LShift | ast.RShift) and not 0 <= right <= _MAX_SHIFT:
            raise ValueError(f"{ast.unparse(node)!r} shifts by {right} (0 to {_MAX_SHIFT} "
                             "bits)")
        if isinstance(node.op, ast.FloorDiv | ast.Mod) and right == 0:
            raise ValueError(f"{ast.unparse(node)!r} divides by zero")
        return _BINARY[type(node.op)](left, right)
    if isinstance(node, ast.UnaryOp) and type(node.op) in _UNARY:
        return _UNARY[type(node.op)](_evaluate(node.operand, names))
    raise ValueError(f"{ast.unparse(node)!r} is not allowed (integers, id, node, "
                     "+ - * // % << >> & | ^ ~ and parentheses)")


def _depth(template: str) -> int:
    """Nesting depth of the expression, from its brackets and unary operators (before any
    parse: a deep expression would exhaust the parser's recursion)."""
    depth = deepest = run = 0
    for ch in template:
        if ch == "(":
            depth += 1
        elif ch == ")":
            depth -= 1
        run = run + 1 if ch in "~-+" else (run if ch.isspace() else 0)
        deepest = max(deepest, depth + run)
    return deepest


def _parse(template: str) -> ast.Expression:
    text = template.strip()
    if len(text) > MAX_TEMPLATE_LENGTH:
        raise ValueError(f"{len(text)} characters (at most {MAX_TEMPLATE_LENGTH})")
    if _depth(text) > MAX_TEMPLATE_DEPTH:
        raise ValueError(f"nested deeper than {MAX_TEMPLATE_DEPTH} levels")
    return ast.parse(text, mode="eval")


def check_template(template: str, field: str, nodes: tuple[int, ...] = (1,)) -> None:
    """Raise ConfigError(field) unless ``template`` is a valid expression of id and node that
    gives a CAN ID for id 1 on every one of ``nodes`` (the DBC's own IDs are checked when the
    bus map is built: canfdi.bus.dbc)."""
    if not isinstance(template, str):
        raise ConfigError(field, f"expected an expression of id and node as a string, got "
                                 f"{type(template).__name__}")
    try:
        tree = _parse(template)
        _evaluate(tree, dict.fromkeys(_NAMES, 1))
    except (SyntaxError, ValueError, RecursionError, MemoryError) as exc:
        detail = exc.msg if isinstance(exc, SyntaxError) else str(exc) or type(exc).__name__
        raise ConfigError(field, f"not a node-id template ({detail}): {brief(template)}"
                          ) from None
    for node in nodes:
        try:
            frame_id(template, 1, node)
        except ValueError as exc:
            raise ConfigError(field, f"{brief(template)} {exc}") from None


def frame_id(template: str | None, dbc_id: int, node: int | None) -> int:
    """The frame ID of the message of DBC ID ``dbc_id`` on drive ``node`` (the DBC's ID when
    there is no template or no node); ValueError when the result is no CAN ID."""
    if template is None or node is None:
        return dbc_id
    try:
        value = _evaluate(_parse(template), {"id": dbc_id, "node": node})
    except ValueError as exc:
        raise ValueError(f"for id 0x{dbc_id:X}, node {node}: {exc}") from None
    if not 0 <= value <= MAX_EXTENDED_ID:
        raise ValueError(f"gives {hex(value)} for id 0x{dbc_id:X}, node {node}: not a CAN ID")
    return value
