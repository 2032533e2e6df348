"""What a bus profile is: the way a plant's drives (and their master) talk on a CAN bus.

A profile says which frames one control period puts on the bus and what each carries. It does
so as a table of *slots*: one slot per frame that is sent in some control periods (a drive's
measurement message, the master's command or SYNC, a remote request, a heartbeat every tenth
period), each with its arbitration ID, DLC, sender, the drive it belongs to and its time
offset within the period. Its encoder fills every slot's payload for a whole block of
samples at once (numpy, no per-frame Python), from the simulated runs of the bus's drives.

The emitter (canfdi.firmware_sim.emitter) does the rest the same way for every profile: pacing on a
real bus or arrival times in a FrameBlock, disturbances (drops, jitter, a corrupted CRC where a
slot has one, a wrong DLC), the interleaving of several drives.

Writing a profile: a module in canfdi/firmware_sim/profiles/ with a `BusProfile` subclass and a
`BusEncoder`, one line in the registry (canfdi/firmware_sim/profiles/__init__.py), a DBC in dbc/ for
each plant it covers, and its timing written down in the module docstring.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, ClassVar

import numpy as np

if TYPE_CHECKING:
    from canfdi.firmware_sim.chunk import SimChunk
    from canfdi.firmware_sim.plants import Plant

__all__ = ["BusEncoder", "BusProfile", "Field", "Slot", "check_nodes", "pack", "source_values"]


@dataclass(frozen=True)
class Slot:
    """One frame the bus carries in some control periods.

    Attributes
    ----------
    name : the message's name, with the node for node-addressed profiles (``TPDO1_node2``).
    frame_id : 11-bit arbitration ID as sent.
    dlc : data length code (of the requested data frame, for a remote frame).
    offset : seconds after the period's start k dt at which the frame leaves.
    sender : ``"DRIVE"`` or ``"MASTER"``.
    drive : index of the drive in the scenario's ``drives`` (None: a bus frame, e.g. SYNC).
    every, phase : sent in the periods k with ``k % every == phase``.
    remote : a remote (RTR) frame: no data.
    crc : byte 0 is a CRC (a ``bad_crc`` disturbance corrupts it).
    """

    name: str
    frame_id: int
    dlc: int
    offset: float
    sender: str = "DRIVE"
    drive: int | None = 0
    every: int = 1
    phase: int = 0
    remote: bool = False
    crc: bool = False

    def __post_init__(self) -> None:
        if not 0 <= self.frame_id <= 0x7FF:
            raise ValueError(f"{self.name}: 0x{self.frame_id:X} is not an 11-bit ID")
        if not 0 <= self.dlc <= 8:
            raise ValueError(f"{self.name}: DLC {self.dlc} is not in 0..8")
        if self.every < 1 or not 0 <= self.phase < self.every:
            raise ValueError(f"{self.name}: every {self.every}, phase {self.phase}")

    def sent(self, k: np.ndarray) -> np.ndarray:
        """(N,) bool: the periods of ``k`` in which this frame is sent."""
        if self.every == 1:
            return np.ones(len(k), dtype=bool)
        return (np.asarray(k) % self.every) == self.phase


class BusEncoder(ABC):
    """A bus's frames for blocks of samples. ``slots`` in send order within a period."""

    slots: tuple[Slot, ...]

    @abstractmethod
    def encode(self, chunks: Sequence[SimChunk]) -> tuple[np.ndarray, dict[str, int]]:
        """Payloads of every slot in every sample of a block.

        Parameters
        ----------
        chunks : one SimChunk per drive (in the scenario's order), all of the same samples.

        Returns
        -------
        data : (N, len(slots), 8) uint8, zero-padded (a slot not sent in a period, or a remote
            frame, holds zeros).
        clipped : signal -> number of values clipped to the signal's range.
        """


class BusProfile(ABC):
    """A way of talking on the bus, for some plants.

    Class attributes
    ----------------
    name : the scenario's ``bus.profile`` (the registry key).
    summary : one line for listings.
    nodes : (lowest, highest) node ID; None when frames carry no node ID (one drive per bus).
    default_node : node of a scenario that names none.
    has_crc : some frames carry a CRC (``bad_crc`` disturbances apply).
    """

    name: ClassVar[str]
    summary: ClassVar[str]
    nodes: ClassVar[tuple[int, int] | None] = None
    default_node: ClassVar[int | None] = None
    has_crc: ClassVar[bool] = False

    @abstractmethod
    def dbc(self, plant: str) -> str | None:
        """Stem of the DBC (in canfdi.dbc) that describes ``plant``'s bus in this profile, or
        None when the profile does not cover the plant."""

    def plants(self) -> list[str]:
        """The plants this profile covers."""
        from canfdi.firmware_sim.plants import PLANTS

        return [name for name in PLANTS if self.dbc(name) is not None]

    @abstractmethod
    def encoder(self, plant: Plant, nodes: Sequence[int | None],
                frame_spacing: float = 130e-6) -> BusEncoder:
        """The encoder of a bus with one drive of ``plant`` per node.

        ``frame_spacing``: seconds between two frames sent back to back (130 us: an 8-byte
        frame at 1 Mbit/s); slot offsets are laid out with it.
        """


# --- vectorised packing of Intel (little-endian) signals ---------------------------------------


@dataclass(frozen=True)
class Field:
    """An Intel signal of a payload: physical = raw * factor + offset (float: raw is float32)."""

    name: str
    start: int
    length: int
    signed: bool = False
    is_float: bool = False
    factor: float = 1.0
    offset: float = 0.0

    def __post_init__(self) -> None:
        if self.is_float and self.length != 32:
            raise ValueError(f"{self.name}: only float32 signals are packed")
        if self.start < 0 or self.start + self.length > 64:
            raise ValueError(f"{self.name}: bits {self.start}..{self.start + self.length - 1} "
                             "do not fit in 8 bytes")

    @classmethod
    def of(cls, signal) -> Field:
        """The field of a cantools Signal (Intel only)."""
        if signal.byte_order != "little_endian":
            raise ValueError(f"{signal.name}: only Intel (little-endian) signals are packed")
        return cls(signal.name, signal.start, signal.length, signal.is_signed, signal.is_float,
                   float(signal.scale), float(signal.offset))

    def raw_limits(self) -> tuple[int, int]:
        if self.signed:
            return -(1 << (self.length - 1)), (1 << (self.length - 1)) - 1
        return 0, (1 << self.length) - 1


def pack(fields: Sequence[tuple[Field, np.ndarray]], count: int,
         clipped: dict[str, int] | None = None, prefix: str = "") -> np.ndarray:
    """Payloads of ``count`` frames with these fields set.

    Parameters
    ----------
    fields : (field, (count,) physical values) pairs.
    count : number of frames.
    clipped : counts of values clipped to a field's raw range (or not finite), updated under
        ``prefix + field.name``.

    Returns
    -------
    (count, 8) uint8 payloads, little-endian, unused bits 0.
    """
    word = np.zeros(count, dtype=np.uint64)
    for field, values in fields:
        v = (np.broadcast_to(np.asarray(values, dtype=float), (count,)) - field.offset
             ) / field.factor
        if field.is_float:
            raw = v.astype("<f4").view("<u4").astype(np.uint64)
        else:
            lo, hi = field.raw_limits()
            ints = np.rint(np.nan_to_num(v, nan=0.0, posinf=hi, neginf=lo))
            outside = (ints < lo) | (ints > hi) | ~np.isfinite(v)
            if outside.any() and clipped is not None:
                key = prefix + field.name
                clipped[key] = clipped.get(key, 0) + int(outside.sum())
            ints = np.clip(ints, lo, hi).astype(np.int64)
            raw = (ints & ((1 << field.length) - 1)).astype(np.uint64)
        word |= raw << np.uint64(field.start)
    return word.astype("<u8").view(np.uint8).reshape(count, 8)


def source_values(chunk: SimChunk, plant: Plant, source) -> np.ndarray:
    """(N,) values of one signal source: ``("u_c", input name)``, ``("z", output name)``,
    ``("ref", reference name)`` or a constant number."""
    if isinstance(source, int | float):
        return np.full(len(chunk), float(source))
    kind, name = source
    names = {"u_c": plant.input_names, "z": plant.output_names,
             "ref": plant.reference_names}[kind]
    return getattr(chunk, kind)[:, names.index(name)]


def check_nodes(nodes: Sequence[int | None], limits: tuple[int, int]) -> list[int]:
    """The node IDs of a bus's drives: integers within ``limits``, distinct, at least one."""
    out = []
    for node in nodes:
        if isinstance(node, bool) or not isinstance(node, int) or not (
                limits[0] <= node <= limits[1]):
            raise ValueError(f"node {node!r}: an integer in {limits[0]}..{limits[1]}")
        out.append(node)
    if not out or len(set(out)) != len(out):
        raise ValueError(f"nodes {out}: one or more distinct node IDs")
    return out
