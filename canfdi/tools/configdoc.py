"""A config file the tools rewrite (`canfdi calibrate -o`, `canfdi identify -o`), edited the way
its user wrote it.

`ConfigDocument` is the config as a round-trip YAML document (ruamel.yaml): comments, key order,
literals (``base: 0x7C0``, quoting) and flow-style matrices survive; a tool sets or deletes the
keys it computed, moves the relative file paths to the output's folder, puts its provenance at
the top and writes it. What the rest of canfdi reads stays PyYAML's (`plain`): every value
written here is one that PyYAML reads back as written (floats with a dot and a signed exponent,
strings quoted where YAML 1.1 would read them as something else).

Examples
--------
>>> doc = ConfigDocument.parse("noise:\\n  measurement: 0.01  # every sensor\\n")
>>> doc.set("noise.measurement", [0.02, 1e-05])
>>> doc.header(["calibrated"])
>>> print(doc.dump(), end="")
# calibrated
noise:
  measurement: [0.02, 1.0e-05] # every sensor
>>> doc.plain()
{'noise': {'measurement': [0.02, 1e-05]}}
"""

from __future__ import annotations

import io
import math
import os
import re
from collections.abc import Mapping
from numbers import Integral, Real
from pathlib import Path
from typing import Any

import yaml
from ruamel.yaml import YAML
from ruamel.yaml.comments import CommentedMap, CommentedSeq
from ruamel.yaml.emitter import Emitter
from ruamel.yaml.error import CommentMark, YAMLError
from ruamel.yaml.events import SequenceEndEvent, SequenceStartEvent
from ruamel.yaml.nodes import SequenceNode
from ruamel.yaml.representer import RoundTripRepresenter
from ruamel.yaml.scalarstring import SingleQuotedScalarString
from ruamel.yaml.serializer import Serializer
from ruamel.yaml.tokens import CommentToken

from canfdi import dbc as shipped_dbc

__all__ = ["FILE_KEYS", "FLOW_ITEMS", "ConfigDocument", "names_file"]

FILE_KEYS = ("bus.dbc", "bus.monitor.dbc")
"""The keys whose values name files (relative to the config's folder unless absolute)."""
FLOW_ITEMS = 16
"""A list of at most this many scalars is written in flow style, ``[a, b, c]``."""
_DIGITS = 10  # significant digits of a float the tools write
_STR = "tag:yaml.org,2002:str"
_OPENER = re.compile(r"^(?:-\s+)*[^#\s-][^#]*:\s*(?:#.*)?$")  # "key:" with its value below
_START = re.compile(r"^---\s*(?:#.*)?$")  # a document-start line with nothing after it


def names_file(value: str) -> bool:
    """Whether a DBC value names a file rather than a DBC shipped in canfdi.dbc; the rule of
    `canfdi.bus.dbc.load_dbc`: a bare name (no folder) that is a shipped DBC's, with or without
    ``.dbc``, is the shipped one, anything else a path."""
    return not (Path(value).name == value
                and value.removesuffix(".dbc") in shipped_dbc.available())


class ConfigDocument:
    """A YAML config loaded for editing: what is not set or deleted is written back as it was.

    Use `load` or `parse`; `plain` is the document as canfdi reads it (PyYAML), `dump` its text.
    """

    def __init__(self, data: CommentedMap, prefix: str, indents: tuple[int, int, int]) -> None:
        self._data = data
        self._prefix = prefix  # a "---" line and what is above it: ruamel drops both
        self._indents = indents
        self._header: list[str] = []

    @classmethod
    def load(cls, path: str | Path) -> ConfigDocument:
        """The config file at ``path``.

        Raises
        ------
        ValueError : the file is missing, unreadable, not YAML (with the line and column) or
            not a mapping; the message names the file.
        """
        path = Path(path)
        try:
            text = path.read_text()
        except FileNotFoundError:
            raise ValueError(f"{path}: file not found") from None
        except OSError as exc:
            raise ValueError(f"cannot read {path}: {exc.strerror}") from None
        return cls.parse(text, str(path))

    @classmethod
    def parse(cls, text: str, source: str = "<text>") -> ConfigDocument:
        """The config whose YAML text is ``text`` (``source`` names it in errors)."""
        try:
            data = _yaml((2, 2, 0)).load(text)
        except YAMLError as exc:
            mark = getattr(exc, "problem_mark", None)
            where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark else ""
            problem = getattr(exc, "problem", None) or str(exc).strip().splitlines()[-1]
            raise ValueError(f"{source}: invalid YAML{where}: {problem}") from None
        if not isinstance(data, CommentedMap):
            raise ValueError(f"{source}: expected a mapping at the top level")
        return cls(data, _prefix(text), _indents(text))

    def plain(self) -> dict:
        """The document as plain Python (dicts, lists, numbers, strings, booleans, None):
        exactly what PyYAML, which reads configs everywhere else in canfdi, reads from `dump`.
        """
        return yaml.safe_load(self.dump())

    def set(self, path: str, value: Any, comment: str | None = None) -> None:
        """Set the dotted key ``path`` (``"model"``, ``"noise.measurement"``) to a plain value.

        An existing key keeps its place and the comments around it; a mapping set over a
        mapping is merged key by key (keys it lacks are deleted, new ones appended), so what
        did not change keeps its literal (``0x7C0``, quotes). A new key goes at the end of its
        mapping (missing parents are made). Floats are written with at most 10 significant
        digits; numeric matrices and lists of up to `FLOW_ITEMS` scalars in flow style, a
        matrix one row per line. ``comment`` (lines without ``#``) goes above the key.

        Raises
        ------
        ValueError : a parent on the path is there but not a mapping.
        TypeError : a value that is not plain (dict, list, str, number, bool, None).
        """
        parent, key, depth = self._parent(path, create=True)
        _assign(parent, key, value)
        if comment is not None:
            parent.yaml_set_comment_before_after_key(
                key, before=comment, indent=_key_column(parent, depth * self._indents[0]))

    def delete(self, path: str) -> None:
        """Delete the dotted key ``path`` (nothing if it is not there); the comment lines
        between it and the next key, which describe what follows, stay."""
        try:
            parent, key, _ = self._parent(path, create=False)
        except KeyError:
            return
        if key in parent:
            _delete(parent, key)

    def relocate_paths(self, source: Path, output: Path) -> None:
        """Make the relative file paths of `FILE_KEYS`, which are relative to the folder of
        ``source`` (the config as read), point at the same files from ``output``'s folder.
        Absolute paths (also ``~/...``) and shipped DBC names (`names_file`) stay."""
        for path in FILE_KEYS:
            try:
                parent, key, _ = self._parent(path, create=False)
            except KeyError:
                continue
            value = parent.get(key)
            if (not isinstance(value, str) or not value or not names_file(value)
                    or Path(value).expanduser().is_absolute()):
                continue
            target = (Path(source).parent / value).resolve()
            folder = Path(output).resolve().parent
            if (folder / value).resolve() == target:
                continue  # already right from there (the same folder): the literal stays
            moved = Path(os.path.relpath(target, folder)).as_posix()
            # keep the user's quoting: a quoted path stays quoted
            parent[key] = type(value)(moved) if type(value) is not str else _node(moved)

    def header(self, lines: list[str]) -> None:
        """Comment lines (without ``#``) for the top of the document, above the file's own
        header comments, which stay; called again, its lines go below the earlier ones."""
        self._header.extend(lines)

    def dump(self) -> str:
        """The document's YAML text."""
        stream = io.StringIO()
        _yaml(self._indents).dump(self._data, stream)
        top = "".join(f"# {line}".rstrip() + "\n" for line in self._header)
        return top + self._prefix + stream.getvalue()

    def write(self, path: str | Path) -> None:
        """Write `dump` to ``path``, making its folder if need be."""
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(self.dump())

    def _parent(self, path: str, create: bool) -> tuple[CommentedMap, str, int]:
        """The mapping holding the last key of ``path``, that key and its depth; KeyError
        when a parent is missing and not ``create``."""
        keys = path.split(".")
        if not all(keys):
            raise ValueError(f"{path!r}: expected a dotted key such as noise.measurement")
        node = self._data
        for depth, key in enumerate(keys[:-1]):
            if key not in node:
                if not create:
                    raise KeyError(key)
                _assign(node, key, {})
            node = node[key]
            if not isinstance(node, CommentedMap):
                where = ".".join(keys[: depth + 1])
                raise ValueError(f"{where}: not a mapping, cannot hold {path}")
        return node, keys[-1], len(keys) - 1


# -- values ------------------------------------------------------------------------------------

def _is_scalar(value: Any) -> bool:
    return value is None or isinstance(value, str | bool | Real)


def _is_matrix(value: list) -> bool:
    return bool(value) and all(isinstance(row, list) and row and all(
        isinstance(x, Real) and not isinstance(x, bool) for x in row) for row in value)


def _node(value: Any) -> Any:
    """A plain value as the round-trip document holds it, styled as `ConfigDocument.set`
    says."""
    if hasattr(value, "tolist"):  # numpy arrays and scalars
        value = value.tolist()
    if value is None or isinstance(value, bool):
        return value
    if isinstance(value, Integral):
        return int(value)
    if isinstance(value, Real):
        return float(f"{float(value):.{_DIGITS}g}")
    if isinstance(value, str):
        # YAML 1.1 (PyYAML) reads yes, on, 1:30, ... as other types: quote what it would
        if yaml.resolver.Resolver().resolve(yaml.ScalarNode, value, (True, False)) != _STR:
            return SingleQuotedScalarString(value)
        return value
    if isinstance(value, Mapping):
        out = CommentedMap()
        for key, item in value.items():
            out[_node(key)] = _node(item)
        out.fa.set_block_style()
        return out
    if isinstance(value, list | tuple):
        items = [_node(x) for x in value]
        seq = CommentedSeq(items)
        if _is_matrix(items) or (len(items) <= FLOW_ITEMS and all(map(_is_scalar, items))):
            seq.fa.set_flow_style()
        else:
            seq.fa.set_block_style()
        return seq
    raise TypeError(f"cannot write {type(value).__name__} {value!r} to a config")


def _same(old: Any, new: Any) -> bool:
    """Whether ``old`` (as loaded) already is the plain ``new``, so that its literal stays.
    A float written with an exponent is rewritten: YAML 1.1 reads ``1.0e9`` as a string."""
    if isinstance(new, bool) or new is None:
        return old is new or (isinstance(old, bool) and old == new)
    if isinstance(new, int):
        return isinstance(old, int) and not isinstance(old, bool) and old == new
    if isinstance(new, float):
        return (isinstance(old, float) and old == new
                and getattr(old, "_exp", None) is None)
    if isinstance(new, str):
        return isinstance(old, str) and old == new
    if isinstance(new, list):
        return (isinstance(old, list) and len(old) == len(new)
                and all(map(_same, old, new)))
    if isinstance(new, Mapping):
        return (isinstance(old, Mapping) and set(old) == set(new)
                and all(_same(old[k], new[k]) for k in new))
    return False


def _assign(parent: CommentedMap, key: Any, value: Any) -> None:
    """``parent[key] = value``, merged into what is there (see `ConfigDocument.set`)."""
    value = _node(value)
    column = _key_column(parent, 0)
    if key not in parent:
        last = next(reversed(parent), None)
        tail = _take_tail(parent, last, column) if last is not None else ""
        parent[key] = value  # appended: what was below the last entry goes below this one
        _give_tail(parent, key, tail)
        return
    old = parent[key]
    if isinstance(old, CommentedMap) and isinstance(value, CommentedMap):
        for gone in [k for k in old if k not in value]:
            _delete(old, gone)
        for k, v in value.items():
            _assign(old, k, v)
        return
    if _same(old, value):
        return
    tail = _take_tail(parent, key, column)
    parent[key] = value
    entry = parent.ca.items.get(key)
    if entry is not None and entry[3] == []:
        entry[3] = None  # left by a block value: ruamel would misplace a flow value after it
    _give_tail(parent, key, tail)


def _delete(parent: CommentedMap, key: Any) -> None:
    """Delete ``parent[key]``; the comment lines below it go below the entry before it (or,
    for the first key, above the one after it)."""
    column = _key_column(parent, 0)
    tail = _take_tail(parent, key, column)
    keys = list(parent)
    at = keys.index(key)
    del parent[key]
    parent.ca.items.pop(key, None)
    if not tail:
        return
    if at > 0:
        _give_tail(parent, keys[at - 1], tail)
    elif len(keys) > 1:
        entry = parent.ca.items.setdefault(keys[1], [None, None, None, None])
        moved = [CommentToken(line.strip() + "\n", CommentMark(column), None)
                 for line in tail.splitlines()]
        entry[1] = moved + (entry[1] or [])


# -- comments ----------------------------------------------------------------------------------
# ruamel keeps the comment lines below an entry (those above the next key) in the comment token
# of the entry's last scalar: replacing or deleting the entry would lose them with it.

def _tail_slot(container: Any, key: Any) -> tuple[list, int]:
    """The comment slot (list, index) after the entry ``container[key]``: that of its last
    scalar, inside a block collection."""
    value = container[key]
    if isinstance(value, CommentedMap | CommentedSeq) and value and not value.fa.flow_style():
        return _tail_slot(value, next(reversed(value)) if isinstance(value, CommentedMap)
                          else len(value) - 1)
    entry = container.ca.items.setdefault(key, [None, None, None, None])
    return entry, 2 if isinstance(container, CommentedMap) else 0


def _take_tail(container: Any, key: Any, column: int) -> str:
    """Remove and return the comment lines below the entry whose key is at ``column``: from
    the first blank line or comment not right of that column on (those right of it continue
    the entry's own comments and stay)."""
    entry, i = _tail_slot(container, key)
    token = entry[i]
    if token is None:
        return ""
    lines = token.value.split("\n")
    cut = next((n for n, line in enumerate(lines[1:-1], 1)
                if not line.strip() or len(line) - len(line.lstrip(" ")) <= column),
               len(lines) - 1)
    own, below = "\n".join(lines[:cut]), "\n".join(lines[cut:])
    if own.strip():
        token.value = own + "\n"
    else:
        entry[i] = None
    return below


def _give_tail(container: Any, key: Any, text: str) -> None:
    """Put comment lines ``text`` below the entry ``container[key]``."""
    if not text:
        return
    entry, i = _tail_slot(container, key)
    if entry[i] is None:
        entry[i] = CommentToken("\n" + text, CommentMark(0), None)
    else:
        entry[i].value = entry[i].value.rstrip("\n") + "\n" + text


def _key_column(mapping: CommentedMap, default: int) -> int:
    """The column of the mapping's keys in the file (``default`` for a new mapping)."""
    for position in _positions(mapping):
        return position[1]
    return default


def _positions(collection: Any) -> list:
    """The [line, column, ...] of each item of a collection as loaded ([] for a new one)."""
    positions = getattr(getattr(collection, "lc", None), "data", None)
    return list(positions.values()) if positions else []


# -- layout ------------------------------------------------------------------------------------

def _prefix(text: str) -> str:
    """A document-start line (``---``) and all above it, as written; '' if there is none."""
    offset = 0
    for line in text.splitlines(keepends=True):
        body = line.strip()
        if _START.match(body):
            return text[: offset + len(line)]
        if body and not body.startswith(("#", "%")):
            return ""
        offset += len(line)
    return ""


def _indents(text: str) -> tuple[int, int, int]:
    """The file's (mapping indent, sequence indent, dash offset) as ruamel's ``indent`` takes
    them, from its first nested mapping and block sequence; PyYAML's (2, 2, 0) if none."""
    mapping = sequence = offset = None
    parent = None  # the column of the key of the last "key:" line
    for line in text.splitlines():
        body = line.lstrip(" ")
        if not body or body.startswith("#"):
            continue
        lead = len(line) - len(body)
        if parent is not None:
            if body.startswith("- ") and lead >= parent and offset is None:
                offset = lead - parent
                sequence = offset + 1 + len(body[1:]) - len(body[1:].lstrip(" "))
            elif not body.startswith("-") and lead > parent and mapping is None:
                mapping = lead - parent
        if mapping is not None and offset is not None:
            break
        dashes = re.match(r"(?:-\s+)*", body)
        parent = lead + (dashes.end() if dashes else 0) if _OPENER.match(body) else None
    return mapping or 2, sequence or 2, 0 if offset is None else offset


class _RowsNode(SequenceNode):
    """A flow sequence to write one item per line (a matrix, row by row)."""

    __slots__ = ()


class _Representer(RoundTripRepresenter):
    """Floats PyYAML reads as floats; matrices marked to be written one row per line."""

    def represent_sequence(self, tag: Any, sequence: Any, flow_style: Any = None
                           ) -> SequenceNode:
        node = super().represent_sequence(tag, sequence, flow_style)
        if node.flow_style and len(sequence) > 1 and all(isinstance(x, list) for x in sequence):
            lines = {position[0] for position in _positions(sequence)}
            # a matrix as loaded keeps its rows' lines; a new one gets one row per line
            if len(lines) != 1:
                node.__class__ = _RowsNode
        return node


def _represent_float(representer: RoundTripRepresenter, value: float) -> Any:
    if math.isnan(value):
        text = ".nan"
    elif math.isinf(value):
        text = ".inf" if value > 0 else "-.inf"
    else:
        mantissa, e, exponent = repr(value).partition("e")
        # YAML 1.1 floats need a dot, and an exponent's sign (repr always writes one)
        text = (mantissa if "." in mantissa else mantissa + ".0") + e + exponent
    return representer.represent_scalar("tag:yaml.org,2002:float", text)


_Representer.add_representer(float, _represent_float)


class _Serializer(Serializer):
    """Hands the representer's row-per-line mark of a sequence to the emitter."""

    def serialize_node(self, node: Any, parent: Any, index: Any) -> None:
        self.emitter.rows_next = isinstance(node, _RowsNode)
        super().serialize_node(node, parent, index)


class _RowsStart(SequenceStartEvent):
    __slots__ = ()


class _Emitter(Emitter):
    """Writes a marked flow sequence's items one per line, aligned after its ``[``."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.rows_next = False  # set by the serializer for the sequence it emits next
        self.row_columns: list[int | None] = []  # per open flow sequence: its rows' column

    def emit(self, event: Any) -> None:
        rows, self.rows_next = self.rows_next, False
        if rows and type(event) is SequenceStartEvent:
            event = _RowsStart(event.anchor, event.ctag, event.implicit, event.start_mark,
                               event.end_mark, flow_style=event.flow_style,
                               comment=event.comment, nr_items=event.nr_items)
        super().emit(event)

    def expect_flow_sequence(self, force_flow_indent: bool | None = False) -> None:
        rows = isinstance(self.event, _RowsStart)
        super().expect_flow_sequence(force_flow_indent)
        self.row_columns.append(self.column if rows else None)

    def expect_first_flow_sequence_item(self) -> None:
        if isinstance(self.event, SequenceEndEvent):
            self.row_columns.pop()
        super().expect_first_flow_sequence_item()

    def expect_flow_sequence_item(self) -> None:
        column = self.row_columns[-1]
        if isinstance(self.event, SequenceEndEvent):
            self.row_columns.pop()
        if column is None or isinstance(self.event, SequenceEndEvent):
            super().expect_flow_sequence_item()
            return
        self.write_indicator(self.flow_seq_separator, False)
        self.write_line_break()
        self.stream.write(" " * column)
        self.column = column
        self.states.append(self.expect_flow_sequence_item)
        self.expect_node(sequence=True)


def _yaml(indents: tuple[int, int, int]) -> YAML:
    """A round-trip loader and dumper with the file's indentation."""
    rt = YAML(typ="rt", pure=True)
    rt.Representer = _Representer
    rt.Serializer = _Serializer
    rt.Emitter = _Emitter
    rt.preserve_quotes = True
    rt.width = 4096  # never fold a long line the user wrote
    mapping, sequence, offset = indents
    rt.indent(mapping=mapping, sequence=sequence, offset=offset)
    return rt
