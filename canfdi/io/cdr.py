"""Row topics as ROS 2 messages: schema encoding ``"ros2msg"``, message encoding ``"cdr"``.

One of MCAP's well-known encodings that Foxglove opens and plots per message without ROS:
a row is a fixed-size little-endian struct (XCDR1, ``00 01 00 00`` then the fields, each
aligned to its size after those four bytes), so that a block of rows is one numpy record
array (`CdrRowEncoder`) rather than a formatted text per row, a third of the bytes of the
JSON row, and no float is rounded on the way.

The schema is a ROS 2 message definition made from the row topic's layout (`row_definition`):
``int64 t_ns`` (the row's own time), the integer fields as int64, each group of named numbers
a message type of float64 fields, and ``string drive`` on a bus of several drives. A field name
is the canfdi name made a ROS 2 field name (`field_names`: ``"s:i_f"`` is ``s_i_f``), and the
canfdi name itself follows in a comment (``float64 s_i_f  # canfdi: "s:i_f"``), from which
`CdrDecoder` gives the message back with canfdi's names.

`CdrDecoder` reads the definitions canfdi writes and the like: primitive types, strings,
nested types, fixed and bounded or unbounded arrays; it raises ValueError for what it does
not take (wide strings, a type it cannot find) and for a message that does not fit its
definition, so that a reader counts such a message as damaged.
"""

from __future__ import annotations

import json
import re
import struct
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray

__all__ = [
    "CDR_HEADER",
    "MESSAGE_ENCODING_CDR",
    "SCHEMA_ENCODING_ROS2",
    "CdrDecoder",
    "CdrRowEncoder",
    "check_field_names",
    "field_names",
    "row_definition",
]

SCHEMA_ENCODING_ROS2 = "ros2msg"
MESSAGE_ENCODING_CDR = "cdr"
CDR_HEADER = b"\x00\x01\x00\x00"
"""XCDR1, little endian, no options: the encapsulation header every message starts with."""
_SEPARATOR = "=" * 80
_NAME_NOTE = re.compile(r'#\s*canfdi:\s*("(?:[^"\\]|\\.)*")\s*$')
_FIELD = re.compile(r"^[a-z](?:[a-z0-9]|_(?!_))*$")


def field_names(names: Sequence[str]) -> list[str]:
    """ROS 2 field names (``[a-z][a-z0-9_]*``, no double or trailing underscore) for canfdi
    names, in order: lower case, every run of other characters an underscore, an ``f`` before
    a leading digit; a name that is one already stays; a repeat gets ``_2``, ``_3``...

    >>> field_names(["a:V", "s:i_f", "omega_r", "a:v", "2x", "__"])
    ['a_v', 's_i_f', 'omega_r', 'a_v_2', 'f2x', 'f']
    """
    out: list[str] = []
    taken: set[str] = set()
    for name in names:
        base = re.sub(r"[^a-z0-9]+", "_", name.lower()).strip("_")
        if not base or not base[0].isalpha():
            base = "f" + base
        field, n = base, 1
        while field in taken:
            n += 1
            field = f"{base}_{n}"
        taken.add(field)
        out.append(field)
    return out


def _type_name(title: str, label: str) -> str:
    """``canfdi/SampleInput`` for the ``input`` list of ``canfdi/msg/Sample`` (a field's type
    is ``package/Type`` in a ROS 2 definition)."""
    return f"{title.replace('/msg/', '/')}{label[:1].upper()}{label[1:]}"


def row_definition(title: str, ints: Sequence[str],
                   groups: Sequence[tuple[str, Sequence[str], str]],
                   drive: bool) -> str:
    """The ROS 2 message definition of a row topic's rows.

    Parameters
    ----------
    title : str
        The row type (``"canfdi/msg/Sample"``); its groups' types are named after it.
    ints : sequence of str
        The integer fields after ``t_ns``.
    groups : sequence of (key, names, label)
        Each group's field, its canfdi names and what they are (``("u", inputs, "input")``);
        groups of the same label share a type.
    drive : bool
        End with ``string drive``.
    """
    lines = [f"# {title}: one row of a canfdi log; each value's canfdi name follows it",
             "int64 t_ns  # the row's time, ns since the epoch"]
    lines += [f"int64 {field_names([key])[0]}" for key in ints]
    types: dict[str, Sequence[str]] = {}
    for key, names, label in groups:
        types.setdefault(label, names)
        lines.append(f"{_type_name(title, label)} {key}")
    if drive:
        lines.append("string drive")
    for label, names in types.items():
        lines += [_SEPARATOR, f"MSG: {_type_name(title, label)}"]
        lines += [f"float64 {field}  # canfdi: {json.dumps(name)}"
                  for field, name in zip(field_names(names), names, strict=True)]
    return "\n".join(lines) + "\n"


class CdrRowEncoder:
    """Rows of fixed layout as CDR messages, a block at a time.

    Parameters
    ----------
    ints : int
        The integer fields after ``t_ns``.
    width : int
        The floats of a row, every group's side by side.
    drive : str, optional
        The ``drive`` string every row ends with.

    Examples
    --------
    >>> encoder = CdrRowEncoder(1, 2, "left")
    >>> data = encoder.encode(np.array([5]), np.array([[3]]), np.array([[0.5, -1.0]]))
    >>> data.shape, bytes(data[0, :4]), bytes(data[0, -9:])
    ((1, 45), b'\\x00\\x01\\x00\\x00', b'\\x05\\x00\\x00\\x00left\\x00')
    """

    __slots__ = ("_drive", "dtype")

    def __init__(self, ints: int, width: int, drive: str | None = None) -> None:
        fields: list[tuple[Any, ...]] = [("header", "V4"), ("t_ns", "<i8"),
                                         ("ints", "<i8", (ints,)), ("floats", "<f8", (width,))]
        self._drive = b""
        if drive is not None:
            text = drive.encode()
            self._drive = struct.pack("<I", len(text) + 1) + text + b"\0"
            fields.append(("drive", f"V{len(self._drive)}"))
        self.dtype = np.dtype(fields)

    def encode(self, t_ns: NDArray[np.int64], ints: NDArray[np.int64],
               floats: NDArray[np.float64]) -> NDArray[np.uint8]:
        """The messages of N rows, (N, size) uint8: times (N,), integers (N, ints), floats
        (N, width)."""
        n = len(t_ns)
        rows = np.empty(n, dtype=self.dtype)
        rows["header"] = np.void(CDR_HEADER)
        rows["t_ns"] = t_ns
        rows["ints"] = np.asarray(ints).reshape(n, -1)
        rows["floats"] = np.asarray(floats).reshape(n, -1)
        if self._drive:
            rows["drive"] = np.void(self._drive)
        return rows.view(np.uint8).reshape(n, self.dtype.itemsize)


# ------------------------------------------------------------------------------------------
# decoding
# ------------------------------------------------------------------------------------------

_PRIMITIVES: dict[str, str] = {
    "bool": "?", "byte": "B", "char": "B", "octet": "B", "int8": "b", "uint8": "B",
    "int16": "h", "uint16": "H", "int32": "i", "uint32": "I", "int64": "q", "uint64": "Q",
    "float32": "f", "float64": "d",
}
_ARRAY = re.compile(r"^(.+?)\[(<=)?(\d*)\]$")
_U32 = struct.Struct("<I")

# A field's reader: (buffer, offset) -> (value, next offset); offsets count after the header.
_Read = Callable[[memoryview, int], tuple[Any, int]]


def _sections(text: str) -> dict[str, list[tuple[str, str, str | None]]]:
    """Each type's fields (type, name, canfdi name) by type name; the root's under ``""``."""
    out: dict[str, list[tuple[str, str, str | None]]] = {}
    current = ""
    out[current] = []
    for raw in text.splitlines():
        line = raw.strip()
        if line and set(line) == {"="}:
            continue
        if line.startswith("MSG:"):
            current = line[4:].strip()
            out[current] = []
            continue
        note = _NAME_NOTE.search(line)
        code = line.split("#", 1)[0].strip()
        if not code:
            continue
        parts = code.split()
        if len(parts) < 2 or "=" in parts[1] or (len(parts) > 2 and parts[2].startswith("=")):
            continue  # a constant: not in the message
        name = json.loads(note.group(1)) if note else None
        out[current].append((parts[0], parts[1], name))
    return out


class CdrDecoder:
    """A message of a ROS 2 definition from its CDR bytes, as a dict (nested types as dicts,
    arrays as lists; a field's key its canfdi name where the definition notes one).

    Parameters
    ----------
    text : str
        The definition: the root type's fields first, then each other type after a line of
        ``=`` and ``MSG: <type>`` (as MCAP's ros2msg schemas hold them).

    Raises
    ------
    ValueError
        For a definition it cannot read.

    Examples
    --------
    >>> text = row_definition("canfdi.Residuals", ["k"], [("r", ["s:i_f"], "residual")], False)
    >>> data = CdrRowEncoder(1, 1).encode(np.array([7]), np.array([[2]]), np.array([[0.25]]))
    >>> CdrDecoder(text)(data[0].tobytes())
    {'t_ns': 7, 'k': 2, 'r': {'s:i_f': 0.25}}
    """

    __slots__ = ("_read", "_types")

    def __init__(self, text: str) -> None:
        self._types = _sections(text)
        self._read = self._struct("")

    def __call__(self, data: bytes | memoryview) -> dict[str, Any]:
        """The message; ValueError when the bytes do not hold one."""
        view = memoryview(data)
        if len(view) < 4 or view[1] != 1:  # only little-endian CDR is written by canfdi
            raise ValueError("not a little-endian CDR message")
        try:
            value, _ = self._read(view[4:], 0)
        except (struct.error, IndexError, UnicodeDecodeError) as error:
            raise ValueError(f"a CDR message shorter than its definition ({error})") from None
        return value

    def _find(self, type_name: str) -> str:
        if type_name in self._types and type_name:
            return type_name
        short = type_name.replace("/msg/", "/")
        for known in self._types:
            if known and known.replace("/msg/", "/") == short:
                return known
        tail = type_name.rsplit("/", 1)[-1]
        found = [k for k in self._types if k and k.rsplit("/", 1)[-1] == tail]
        if len(found) == 1:
            return found[0]
        raise ValueError(f"a ROS 2 definition without the type {type_name}")

    def _struct(self, type_name: str, seen: tuple[str, ...] = ()) -> _Read:
        """A type's reader: each run of fixed-size fields (numbers, fixed arrays and types of
        them: a row's all but its drive) one struct unpack, the others field by field."""
        if type_name in seen:
            raise ValueError(f"the ROS 2 type {type_name} contains itself")
        inner = (*seen, type_name)
        # Each step puts its fields into the message and returns where the next one starts.
        steps: list[Callable[[memoryview, int, dict[str, Any]], int]] = []
        run: _FixedRun | None = None
        for kind, name, key in self._types[type_name]:
            key = name if key is None else key
            flat = self._flat(kind, inner)
            if flat is None:
                steps.append(_one(key, self._field(kind, inner)))
                run = None
            elif run is not None:
                run.add(key, *flat)
            else:
                run = _FixedRun(key, *flat)
                steps.append(run.read)

        def read(buf: memoryview, p: int) -> tuple[Any, int]:
            out: dict[str, Any] = {}
            for step in steps:
                p = step(buf, p, out)
            return out, p
        return read

    def _flat(self, kind: str, seen: tuple[str, ...]
              ) -> tuple[str, Callable[[Any], Any]] | None:
        """A fixed-size field's struct codes and how to build its value from an iterator over
        the unpacked numbers; None for a field of variable size."""
        array = _ARRAY.match(kind)
        if array:
            if not array.group(3) or array.group(2):
                return None
            item = self._flat(array.group(1), seen)
            if item is None:
                return None
            count, build = int(array.group(3)), item[1]
            return item[0] * count, lambda values: [build(values) for _ in range(count)]
        code = _PRIMITIVES.get(kind)
        if code is not None:
            return code, next
        if kind.split("<=", 1)[0] in ("string", "wstring"):
            return None
        type_name = self._type_of(kind)
        if type_name in seen:
            raise ValueError(f"the ROS 2 type {type_name} contains itself")
        parts = [(name if key is None else key, self._flat(k, (*seen, type_name)))
                 for k, name, key in self._types[type_name]]
        if any(flat is None for _, flat in parts):
            return None
        codes = "".join(flat[0] for _, flat in parts)  # type: ignore[index]
        builds = [(key, flat[1]) for key, flat in parts]  # type: ignore[index]
        return codes, lambda values: {key: build(values) for key, build in builds}

    def _field(self, kind: str, seen: tuple[str, ...]) -> _Read:
        array = _ARRAY.match(kind)
        if array:
            item = self._field(array.group(1), seen)
            if array.group(3) and not array.group(2):
                count = int(array.group(3))
                return lambda buf, p: _items(item, buf, p, count)

            def sequence(buf: memoryview, p: int) -> tuple[Any, int]:
                p += -p % 4
                (n,) = _U32.unpack_from(buf, p)
                if n > len(buf):  # an element takes a byte at least
                    raise struct.error(f"a sequence of {n} items in {len(buf)} bytes")
                return _items(item, buf, p + 4, n)
            return sequence
        base = kind.split("<=", 1)[0]
        if base == "string":
            return _string
        code = _PRIMITIVES.get(base)
        if code is not None:
            one = struct.Struct("<" + code)
            size = one.size

            def primitive(buf: memoryview, p: int) -> tuple[Any, int]:
                p += -p % size
                return one.unpack_from(buf, p)[0], p + size
            return primitive
        if base == "wstring":
            raise ValueError("wide strings (wstring) are not read")
        return self._struct(self._type_of(base), seen)

    def _type_of(self, kind: str) -> str:
        """The type a field of this kind holds (ROS 1's time and duration are ROS 2's
        builtin_interfaces types)."""
        if kind in ("time", "duration"):
            kind = f"builtin_interfaces/{kind.capitalize()}"
        return self._find(kind)


class _FixedRun:
    """Consecutive fixed-size fields: one struct per start offset modulo 8 (CDR aligns each
    number to its size, at most 8), unpacked at once."""

    __slots__ = ("builds", "codes", "structs")

    def __init__(self, key: str, codes: str, build: Callable[[Any], Any]) -> None:
        self.codes = ""
        self.builds: list[tuple[str, Callable[[Any], Any]]] = []
        self.structs: dict[int, struct.Struct] = {}
        self.add(key, codes, build)

    def add(self, key: str, codes: str, build: Callable[[Any], Any]) -> None:
        self.codes += codes
        self.builds.append((key, build))

    def _struct(self, start: int) -> struct.Struct:
        fmt, p = [], start
        for code in self.codes:
            size = struct.calcsize(code)
            pad = -p % size
            fmt.append("x" * pad + code)
            p += pad + size
        made = self.structs[start] = struct.Struct("<" + "".join(fmt))
        return made

    def read(self, buf: memoryview, p: int, out: dict[str, Any]) -> int:
        one = self.structs.get(p % 8) or self._struct(p % 8)
        values = iter(one.unpack_from(buf, p))
        for key, build in self.builds:
            out[key] = build(values)
        return p + one.size


def _one(key: str, field: _Read) -> Callable[[memoryview, int, dict[str, Any]], int]:
    """A variable-size field as a step of its type's reader."""
    def put(buf: memoryview, p: int, out: dict[str, Any]) -> int:
        out[key], p = field(buf, p)
        return p
    return put


def _items(item: _Read, buf: memoryview, p: int, n: int) -> tuple[list[Any], int]:
    out = []
    for _ in range(n):
        value, p = item(buf, p)
        out.append(value)
    return out, p


def _string(buf: memoryview, p: int) -> tuple[str, int]:
    p += -p % 4
    (n,) = _U32.unpack_from(buf, p)
    if p + 4 + n > len(buf) or n == 0:
        raise struct.error("a string beyond the message")
    return bytes(buf[p + 4 : p + 3 + n]).decode(), p + 4 + n


def check_field_names(fields: Sequence[str]) -> bool:
    """Whether every name is a ROS 2 field name."""
    return all(_FIELD.match(f) for f in fields)
