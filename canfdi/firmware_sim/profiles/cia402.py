"""A CANopen CiA 402 drive on the bus with its master (SYNC, PDOs, heartbeat; no CRC, no counter).

The drive is described by its electronic data sheet (``dc_motor_cia402.eds`` beside this
module): the python-canopen package reads it (``canopen.import_od``) and gives the PDO
mappings of node n (``LocalNode.tpdo/rpdo.read(from_od=True)``: COB-IDs with $NODEID resolved,
each mapped object's bit offset, length, data type and scale factor), the SYNC COB-ID (0x1005),
the communication cycle period (0x1006) and the producer heartbeat time (0x1017). Payloads are
then packed with numpy a block of samples at a time. ``dbc/dc_motor_cia402.dbc`` describes the
same bus for node 1, as a vendor publishes it for CAN tools; tests check the two agree.

Plant ``dc_motor`` (V in; i_f, i_a, i_f_plus_i_a, omega_r out), node n, dt = 10 ms:

============== ========= ===== ======== =================================================
frame          COB-ID    DLC   sender   content
============== ========= ===== ======== =================================================
SYNC           0x080     0     MASTER   (no data)
TPDO1_node<n>  0x180+n   6     DRIVE    0x6041 Statusword U16 (0x0237), 0x606C Velocity
                                        actual value I32 in 0.01 rpm (omega_r)
TPDO2_node<n>  0x280+n   6     DRIVE    0x2101 field, 0x2102 armature, 0x2103 line current,
                                        I16 in mA (i_f, i_a, i_f_plus_i_a)
RPDO1_node<n>  0x200+n   6     MASTER   0x6040 Controlword U16 (0x000F), 0x2001 Target
                                        voltage I32 in mV (V: vendor-specific mode -1)
HEARTBEAT_n    0x700+n   1     DRIVE    NMT state 0x05 (operational), every 100 ms
============== ========= ===== ======== =================================================

Timing of control period k (t = k dt + offset; s = ``frame_spacing``, 130 us by default;
several drives: their frames of one kind follow each other in COB-ID order, which is also
the order CAN arbitration gives them):

- SYNC k at +0. The drive samples its measurements z(k) at SYNC k.
- TPDO1, TPDO2 of every node (transmission type 1: every SYNC) at +s, +2s, ...: z(k).
- RPDO1 of every node 0.5 ms (the master's computation) after the last TPDO: the command
  u_c(k) the master computed from z(k). RPDO1 has transmission type 255, so the drive applies
  it on reception, for the rest of period k: the plant's zero-order hold u(k) over
  [k dt, (k+1) dt) neglects these ~0.8 ms, as the model of any digital loop neglects its
  computation delay.
- HEARTBEAT of every node after the RPDOs, in the periods with k % 10 == 0 (100 ms).
- SYNC k+1 at (k+1) dt.

So every frame of period k lies between SYNC k and SYNC k+1 (one drive: the last at
+0.89 ms), and a monitor with a ``trigger`` clock on SYNC forms, at SYNC k+1, the sample of
period k: the newest TPDO values (z(k)) and the newest RPDO value (u_c(k)), each about 9 ms
old.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from canfdi.firmware_sim.profiles.base import (
    BusEncoder,
    BusProfile,
    Field,
    Slot,
    check_nodes,
    pack,
    source_values,
)

if TYPE_CHECKING:
    from canfdi.firmware_sim.chunk import SimChunk
    from canfdi.firmware_sim.plants import Plant

__all__ = ["MASTER_DELAY", "Cia402Encoder", "Cia402Profile", "DeviceSpec", "PdoSpec",
           "read_device"]

HERE = Path(__file__).resolve().parent
MASTER_DELAY = 0.5e-3
"""Seconds the master takes from the last TPDO of a period to its first RPDO."""
OPERATIONAL = 0x05
HEARTBEAT_BASE = 0x700

# plant -> (DBC stem, EDS file beside this module)
_DEVICES = {"dc_motor": ("dc_motor_cia402", "dc_motor_cia402.eds")}

# plant -> what the master (RPDO) or the drive (TPDO) puts in each mapped object: a plant
# input / output by name, or a constant.
_SOURCES = {
    "dc_motor": {
        0x6040: 0x000F,                  # Controlword: enable operation
        0x2001: ("u_c", "V"),            # Target voltage
        0x6041: 0x0237,                  # Statusword: operation enabled, voltage enabled, remote
        0x606C: ("z", "omega_r"),        # Velocity actual value
        0x2101: ("z", "i_f"),            # Field current actual value
        0x2102: ("z", "i_a"),            # Armature current actual value
        0x2103: ("z", "i_f_plus_i_a"),   # Line current actual value
    },
}


@dataclass(frozen=True)
class PdoSpec:
    """One enabled PDO of a node, as its EDS maps it.

    kind : "TPDO" or "RPDO"; number : 1-based; every : SYNCs per transmission (TPDO
    transmission type 1..240), 1 otherwise; fields : (Field, OD index) per mapped object.
    """

    kind: str
    number: int
    cob_id: int
    dlc: int
    every: int
    fields: tuple[tuple[Field, int], ...]

    def name(self, node: int) -> str:
        return f"{self.kind}{self.number}_node{node}"


@dataclass(frozen=True)
class DeviceSpec:
    """What a node's EDS says about its bus traffic."""

    node: int
    sync_id: int
    cycle_us: int
    heartbeat_ms: int
    tpdos: tuple[PdoSpec, ...]
    rpdos: tuple[PdoSpec, ...]


def read_device(eds: str | Path, node: int) -> DeviceSpec:
    """Node ``node``'s PDOs, SYNC COB-ID, cycle and heartbeat time from an EDS (python-canopen).
    """
    import canopen
    from canopen.objectdictionary import FLOAT_TYPES, SIGNED_TYPES

    od = canopen.import_od(str(eds), node)
    device = canopen.LocalNode(node, od)
    # PdoMap.read registers each COB-ID with the node's network: an unconnected Network is
    # enough (nothing is sent or received here).
    canopen.Network().add_node(device)
    pdos = []
    for kind, maps in (("TPDO", device.tpdo), ("RPDO", device.rpdo)):
        maps.read(from_od=True)
        for number, pdo in sorted(maps.map.items()):
            if not pdo.enabled or not pdo.map:
                continue
            trans = pdo.trans_type or 0
            every = trans if kind == "TPDO" and 1 <= trans <= 240 else 1
            fields = tuple(
                (Field(name=var.name, start=var.offset, length=var.length,
                       signed=var.od.data_type in SIGNED_TYPES,
                       is_float=var.od.data_type in FLOAT_TYPES, factor=float(var.od.factor)),
                 var.od.index)
                for var in pdo.map)
            pdos.append(PdoSpec(kind, number, pdo.cob_id & 0x7FF, (pdo.length + 7) // 8, every,
                                fields))
    return DeviceSpec(node=node, sync_id=int(od[0x1005].default) & 0x7FF,
                      cycle_us=int(od[0x1006].default), heartbeat_ms=int(od[0x1017].default),
                      tpdos=tuple(p for p in pdos if p.kind == "TPDO"),
                      rpdos=tuple(p for p in pdos if p.kind == "RPDO"))


class Cia402Encoder(BusEncoder):
    """SYNC, every node's TPDOs and RPDOs and heartbeats, laid out as the module says."""

    def __init__(self, plant: Plant, nodes: Sequence[int], frame_spacing: float,
                 eds: Path, sources: dict[int, object]) -> None:
        self.plant = plant
        self.nodes = list(nodes)
        self.devices = [read_device(eds, node) for node in self.nodes]
        dev = self.devices[0]
        if dev.cycle_us != round(plant.dt * 1e6):
            raise ValueError(f"{eds.name}: communication cycle period 0x1006 is {dev.cycle_us} "
                             f"us, the plant's dt is {plant.dt} s")
        every_hb = dev.heartbeat_ms / (plant.dt * 1000)
        if dev.heartbeat_ms <= 0 or abs(every_hb - round(every_hb)) > 1e-9:
            raise ValueError(f"{eds.name}: heartbeat time {dev.heartbeat_ms} ms is not a "
                             f"multiple of the control period")
        for d in self.devices:
            for pdo in (*d.tpdos, *d.rpdos):
                for field, index in pdo.fields:
                    if index not in sources:
                        raise ValueError(f"{eds.name}: object 0x{index:04X} ({field.name}) of "
                                         f"{pdo.name(d.node)} has no source for {plant.name}")
        slots: list[Slot] = [Slot("SYNC", dev.sync_id, 0, 0.0, sender="MASTER", drive=None)]
        fills: list[tuple[int, PdoSpec] | None] = [None]
        t = 0.0
        tx = sorted(((p.cob_id, i, p) for i, d in enumerate(self.devices) for p in d.tpdos),
                    key=lambda e: e[0])
        for cob_id, i, pdo in tx:
            t += frame_spacing
            slots.append(Slot(pdo.name(self.nodes[i]), cob_id, pdo.dlc, t, sender="DRIVE",
                              drive=i, every=pdo.every))
            fills.append((i, pdo))
        rx = sorted(((p.cob_id, i, p) for i, d in enumerate(self.devices) for p in d.rpdos),
                    key=lambda e: e[0])
        t += MASTER_DELAY - frame_spacing
        for cob_id, i, pdo in rx:
            t += frame_spacing
            slots.append(Slot(pdo.name(self.nodes[i]), cob_id, pdo.dlc, t, sender="MASTER",
                              drive=i))
            fills.append((i, pdo))
        self._heartbeats = []
        for i, node in enumerate(self.nodes):
            t += frame_spacing
            self._heartbeats.append(len(slots))
            slots.append(Slot(f"HEARTBEAT_node{node}", HEARTBEAT_BASE + node, 1, t,
                              sender="DRIVE", drive=i, every=round(every_hb)))
            fills.append(None)
        if t >= plant.dt:
            raise ValueError(f"{len(self.nodes)} drives' frames take {t * 1e3:.2f} ms, more "
                             f"than the control period ({plant.dt * 1e3:g} ms)")
        self.slots = tuple(slots)
        self._fills = fills
        self._sources = sources

    def encode(self, chunks: Sequence[SimChunk]) -> tuple[np.ndarray, dict[str, int]]:
        n = len(chunks[0])
        data = np.zeros((n, len(self.slots), 8), dtype=np.uint8)
        clipped: dict[str, int] = {}
        for j, fill in enumerate(self._fills):
            if fill is None:
                continue
            i, pdo = fill
            values = [(field, source_values(chunks[i], self.plant, self._sources[index]))
                      for field, index in pdo.fields]
            data[:, j] = pack(values, n, clipped, prefix=f"{self.slots[j].name}.")
        for j in self._heartbeats:
            data[:, j, 0] = OPERATIONAL
        return data, clipped


class Cia402Profile(BusProfile):
    name = "cia402"
    summary = ("CANopen CiA 402 drive(s) and master: SYNC, RPDO command, TPDO measurements, "
               "heartbeat; no CRC, no counter")
    nodes = (1, 127)
    default_node = 1
    has_crc = False

    def dbc(self, plant: str) -> str | None:
        return _DEVICES[plant][0] if plant in _DEVICES else None

    def eds(self, plant: str) -> Path:
        """The EDS of ``plant``'s drive."""
        return HERE / _DEVICES[plant][1]

    def encoder(self, plant: Plant, nodes: Sequence[int | None],
                frame_spacing: float = 130e-6) -> Cia402Encoder:
        if plant.name not in _DEVICES:
            raise ValueError(f"the cia402 profile does not cover plant {plant.name!r}")
        checked = check_nodes(nodes, self.nodes)
        return Cia402Encoder(plant, checked, frame_spacing, self.eds(plant.name),
                             _SOURCES[plant.name])

