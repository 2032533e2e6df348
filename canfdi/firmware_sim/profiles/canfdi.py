"""canfdi's own bus: every drive message carries canfdi's CRC-8 and alive counter.

One drive per bus (the DBCs have no node IDs). Every control period k the drive sends each
message of its plant's DBC (``Plant.dbc``, sender DRIVE) once, in ID order, back to back from
k dt on (``frame_spacing`` apart): the command u_c(k), the measurements z(k) and the
references, each frame with the counter k mod 256 in byte 1 and the CRC-8 over the Data ID and
the payload in byte 0 (dbc/README.md). The monitor's counter clock assembles sample k from the
frames with counter k.

=========== ========= ============ ====================================================
frame       sender    offset       content
=========== ========= ============ ====================================================
DRIVE_* i   DRIVE     i spacing    the plant's signals by name, CRC, Counter = k mod 256
=========== ========= ============ ====================================================
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np

from canfdi import dbc as dbc_files
from canfdi.bus.codec import MessageLayout, compile_layout
from canfdi.bus.e2e import protect_batch
from canfdi.firmware_sim.profiles.base import BusEncoder, BusProfile, Slot

if TYPE_CHECKING:
    from canfdi.firmware_sim.chunk import SimChunk
    from canfdi.firmware_sim.plants import Plant

__all__ = ["CanfdiEncoder", "CanfdiProfile", "FrameEncoder"]

_E2E_SIGNALS = {"CRC", "Counter"}


class FrameEncoder:
    """Turns simulated samples into the drive's protected frames, a block at a time.

    The DBC is the contract: every signal of a DRIVE message other than CRC and Counter must be
    one of the plant's input, output or reference names.
    """

    def __init__(self, plant: Plant, database=None) -> None:
        database = database or dbc_files.load(plant.dbc)
        sources = {}
        for j, name in enumerate(plant.input_names):
            sources[name] = ("u_c", j)
        for j, name in enumerate(plant.output_names):
            sources[name] = ("z", j)
        for j, name in enumerate(plant.reference_names):
            sources[name] = ("ref", j)
        self.layouts: list[MessageLayout] = []
        self._sources: list[list[tuple[str, str, int]]] = []
        for message in sorted(database.messages, key=lambda m: m.frame_id):
            if "DRIVE" not in (message.senders or []):
                continue
            layout = compile_layout(message)
            mapping = []
            for sig in layout.signals:
                if sig.name in _E2E_SIGNALS:
                    continue
                if sig.name not in sources:
                    raise ValueError(f"{plant.dbc}: {message.name}.{sig.name} is not an input, "
                                     f"output or reference of {plant.name}")
                mapping.append((sig.name, *sources[sig.name]))
            self.layouts.append(layout)
            self._sources.append(mapping)
        if not self.layouts:
            raise ValueError(f"{plant.dbc}: no message is sent by DRIVE")

    def encode(self, chunk: SimChunk) -> tuple[list[np.ndarray], dict[str, int]]:
        """Protected payloads of every drive message for every sample of the chunk.

        Returns
        -------
        payloads : one (N, dlc) uint8 array per message, in ``self.layouts`` order.
        clipped : signal name -> number of values clipped to the DBC range.
        """
        n = len(chunk)
        counters = chunk.k.astype(np.int64) & 0xFF
        out, clipped = [], {}
        for layout, mapping in zip(self.layouts, self._sources, strict=True):
            values = {name: getattr(chunk, src)[:, j] for name, src, j in mapping}
            payload, clip = layout.encode(values, n)
            for name, count in clip.items():
                clipped[name] = clipped.get(name, 0) + count
            out.append(protect_batch(layout.frame_id, payload, counters))
        return out, clipped


class CanfdiEncoder(BusEncoder):
    """The one drive's DBC messages as slots, in ID order, ``frame_spacing`` apart."""

    def __init__(self, plant: Plant, frame_spacing: float) -> None:
        self.frames = FrameEncoder(plant)
        self.slots = tuple(Slot(name=lay.name, frame_id=lay.frame_id, dlc=lay.dlc,
                                offset=i * frame_spacing, sender="DRIVE", drive=0, crc=True)
                           for i, lay in enumerate(self.frames.layouts))

    def encode(self, chunks: Sequence[SimChunk]) -> tuple[np.ndarray, dict[str, int]]:
        (chunk,) = chunks
        payloads, clipped = self.frames.encode(chunk)
        data = np.zeros((len(chunk), len(payloads), 8), dtype=np.uint8)
        for i, p in enumerate(payloads):
            data[:, i, : p.shape[1]] = p
        return data, clipped


class CanfdiProfile(BusProfile):
    name = "canfdi"
    summary = "canfdi's own DBCs: CRC-8 + alive counter in every drive frame, one drive per bus"
    nodes = None
    default_node = None
    has_crc = True

    def dbc(self, plant: str) -> str | None:
        from canfdi.firmware_sim.plants import PLANTS, make_plant

        if plant not in PLANTS:
            return None
        own = make_plant(plant).dbc
        return None if own is None else own.removesuffix(".dbc")

    def encoder(self, plant: Plant, nodes: Sequence[int | None],
                frame_spacing: float = 130e-6) -> CanfdiEncoder:
        if list(nodes) != [None]:
            raise ValueError(f"the canfdi profile carries one drive without a node ID, got "
                             f"nodes {list(nodes)}")
        return CanfdiEncoder(plant, frame_spacing)
