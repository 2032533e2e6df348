"""A node-ID float protocol, as open motor controllers speak it (ODrive's CAN Simple and alike).

The frame ID is ``node << 5 | cmd`` (11-bit; node 0..62, 63 being the broadcast address),
setpoints and estimates are IEEE float32, little-endian: the DC motor's in SI units (ODrive
sends turns and turns/s, as the servo axis does; a DBC factor of 2 pi would convert, but
canfdi.bus.codec does not apply a factor to float signals yet); no CRC, no counter. The drive
sends its encoder estimates every control period on its own, the master sends the setpoint
every period and polls the currents with remote frames (RTR), which the drive answers with the
data frame of the same ID. The plant's DBC (``dbc/dc_motor_float.dbc``,
``dbc/servo_axis_float.dbc``) describes node 0 (IDs = cmd); the encoder reads its message
layouts from there.

Plant ``dc_motor`` (V in; i_f, i_a, i_f_plus_i_a, omega_r out), node n, dt = 10 ms:

======================== ============ ==== ========= ========================================
frame                    ID           DLC  sender    content
======================== ============ ==== ========= ========================================
Get_Encoder_Estimates    n<<5 | 0x09  8    DRIVE     Pos_Estimate (rad), Vel_Estimate
                                                     (rad/s: omega_r)
Get_Currents (RTR)       n<<5 | 0x14  8    MASTER    remote frame, no data
Get_Currents             n<<5 | 0x14  8    DRIVE     Field_Current (i_f), Armature_Current (i_a)
Get_Bus_Voltage_Current  n<<5 | 0x17  8    MASTER    remote frame, no data
(RTR)
Get_Bus_Voltage_Current  n<<5 | 0x17  8    DRIVE     Bus_Voltage (320 V), Bus_Current
                                                     (i_f_plus_i_a)
Set_Input_Voltage        n<<5 | 0x0E  4    MASTER    Input_Voltage (V)
Heartbeat                n<<5 | 0x01  8    DRIVE     Axis_Error 0, Axis_State 8 (closed loop),
                                                     every 100 ms
======================== ============ ==== ========= ========================================

Timing of control period k (t = k dt + offset; s = ``frame_spacing``, 130 us by default;
several drives: the estimates of all nodes first, then each node's polls in node order):

- +0: Get_Encoder_Estimates of every node: omega_r(k) sampled at k dt (and the shaft angle,
  its running integral).
- +s ...: for each node, the master's RTR for Get_Currents, the drive's answer (i_f(k),
  i_a(k)), then the same for Get_Bus_Voltage_Current (i_f_plus_i_a(k)).
- 0.5 ms (the master's computation) after the last answer: Set_Input_Voltage of every node,
  u_c(k) computed from z(k); the drive applies it on reception, for the rest of period k (the
  model's zero-order hold neglects the ~1 ms).
- then Heartbeat of every node, in the periods with k % 10 == 0.

Plant ``servo_axis`` (Input_Torque in; Iq_Setpoint, Iq_Measured, Vel_Estimate, Pos_Estimate
out), an ODrive in torque control with ODrive's own units and message layouts
(``dbc/servo_axis_float.dbc``; ODrive's published ``odrive-cansimple.dbc`` decodes the same
frames), node n, dt = 10 ms:

======================== ============ ==== ========= ========================================
frame                    ID           DLC  sender    content
======================== ============ ==== ========= ========================================
Get_Encoder_Estimates    n<<5 | 0x09  8    DRIVE     Pos_Estimate (turns), Vel_Estimate
                                                     (turns/s)
Get_Iq (RTR)             n<<5 | 0x14  8    MASTER    remote frame, no data
Get_Iq                   n<<5 | 0x14  8    DRIVE     Iq_Setpoint, Iq_Measured (A)
Set_Input_Torque         n<<5 | 0x0E  8    MASTER    Input_Torque (Nm)
Heartbeat                n<<5 | 0x01  8    DRIVE     Axis_Error 0, Axis_State 8 (closed loop),
                                                     every 100 ms
======================== ============ ==== ========= ========================================

One DC motor drive: the period's frames lie in [k dt, k dt + 1.15 ms] (a servo axis, with one
polled message: [k dt, k dt + 0.89 ms]). There is no SYNC: a monitor samples this bus with
a ``grid`` clock (period dt, phase dt/2: each sample in the quiet middle of a period, holding
that period's burst). A ``trigger`` on the estimates frame would not do: the sample it closes
would pair omega_r(k+1) with the currents and command of period k.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
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

__all__ = ["CMD_MASK", "MASTER_DELAY", "FloatBusSpec", "FloatNodeEncoder", "FloatNodeProfile",
           "frame_id"]

CMD_MASK = 0x1F
NODE_SHIFT = 5
MASTER_DELAY = 0.5e-3
"""Seconds the master takes from the last polled answer of a period to its setpoints."""


def frame_id(node: int, cmd: int) -> int:
    """The 11-bit ID of command ``cmd`` (or a node-0 DBC ID) on node ``node``."""
    return (node << NODE_SHIFT) | (cmd & CMD_MASK)


@dataclass(frozen=True)
class FloatBusSpec:
    """A plant's messages in the protocol and what each signal carries.

    estimates : the drive's cyclic messages (every period); polled : messages the master polls
    by RTR every period; commands : the master's setpoints; heartbeat : the drive's heartbeat.
    sources : message -> signal -> a plant input/output (``("u_c"|"z", name)``), a constant,
    or ``("angle", output name)``: the running integral of an angular speed (rad/s), in rad.
    """

    dbc: str
    estimates: tuple[str, ...]
    polled: tuple[str, ...]
    commands: tuple[str, ...]
    heartbeat: str
    sources: dict[str, dict[str, object]]


_BUSES = {
    "dc_motor": FloatBusSpec(
        dbc="dc_motor_float",
        estimates=("Get_Encoder_Estimates",),
        polled=("Get_Currents", "Get_Bus_Voltage_Current"),
        commands=("Set_Input_Voltage",),
        heartbeat="Heartbeat",
        sources={
            "Get_Encoder_Estimates": {"Pos_Estimate": ("angle", "omega_r"),
                                      "Vel_Estimate": ("z", "omega_r")},
            "Get_Currents": {"Field_Current": ("z", "i_f"), "Armature_Current": ("z", "i_a")},
            "Get_Bus_Voltage_Current": {"Bus_Voltage": 320.0,
                                        "Bus_Current": ("z", "i_f_plus_i_a")},
            "Set_Input_Voltage": {"Input_Voltage": ("u_c", "V")},
            "Heartbeat": {"Axis_Error": 0, "Axis_State": 8, "Procedure_Result": 0,
                          "Trajectory_Done_Flag": 0},
        },
    ),
    "servo_axis": FloatBusSpec(
        dbc="servo_axis_float",
        estimates=("Get_Encoder_Estimates",),
        polled=("Get_Iq",),
        commands=("Set_Input_Torque",),
        heartbeat="Heartbeat",
        sources={
            "Get_Encoder_Estimates": {"Pos_Estimate": ("z", "Pos_Estimate"),
                                      "Vel_Estimate": ("z", "Vel_Estimate")},
            "Get_Iq": {"Iq_Setpoint": ("z", "Iq_Setpoint"),
                       "Iq_Measured": ("z", "Iq_Measured")},
            "Set_Input_Torque": {"Input_Torque": ("u_c", "Input_Torque")},
            "Heartbeat": {"Axis_Error": 0, "Axis_State": 8},
        },
    ),
}


@dataclass(frozen=True)
class _Fill:
    drive: int
    message: str
    fields: tuple[tuple[Field, object], ...]


class FloatNodeEncoder(BusEncoder):
    """Every node's estimates, polls and answers, setpoints and heartbeats, as the module
    says."""

    def __init__(self, plant: Plant, nodes: Sequence[int], frame_spacing: float,
                 spec: FloatBusSpec) -> None:
        from canfdi import dbc as dbc_files

        self.plant = plant
        self.nodes = list(nodes)
        database = dbc_files.load(spec.dbc)
        messages = {m.name: m for m in database.messages}
        used = (*spec.estimates, *spec.polled, *spec.commands, spec.heartbeat)
        for name in used:
            if name not in messages:
                raise ValueError(f"{spec.dbc}.dbc has no message {name}")
            unknown = {s.name for s in messages[name].signals} - set(spec.sources[name])
            if unknown:
                raise ValueError(f"{spec.dbc}.dbc: {name}.{sorted(unknown)[0]} has no source "
                                 f"for {plant.name}")
        heartbeat = messages[spec.heartbeat]
        every_hb = (heartbeat.cycle_time or 0) / (plant.dt * 1000)
        if every_hb < 1 or abs(every_hb - round(every_hb)) > 1e-9:
            raise ValueError(f"{spec.dbc}.dbc: {spec.heartbeat} cycle time is not a multiple "
                             "of the control period")
        slots: list[Slot] = []
        fills: list[_Fill | None] = []

        def add(name: str, i: int, t: float, sender: str, remote: bool = False,
                every: int = 1) -> None:
            msg = messages[name]
            slots.append(Slot(f"{name}_node{self.nodes[i]}", frame_id(self.nodes[i],
                                                                        msg.frame_id),
                              msg.length, t, sender=sender, drive=i, every=every,
                              remote=remote))
            fills.append(None if remote else _Fill(i, name, tuple(
                (Field.of(sig), spec.sources[name][sig.name]) for sig in msg.signals)))

        t = -frame_spacing
        for name in spec.estimates:
            for i in range(len(self.nodes)):
                t += frame_spacing
                add(name, i, t, "DRIVE")
        for i in range(len(self.nodes)):
            for name in spec.polled:
                t += frame_spacing
                add(name, i, t, "MASTER", remote=True)
                t += frame_spacing
                add(name, i, t, "DRIVE")
        t += MASTER_DELAY - frame_spacing
        for name in spec.commands:
            for i in range(len(self.nodes)):
                t += frame_spacing
                add(name, i, t, "MASTER")
        for i in range(len(self.nodes)):
            t += frame_spacing
            add(spec.heartbeat, i, t, "DRIVE", every=round(every_hb))
        if t >= plant.dt:
            raise ValueError(f"{len(self.nodes)} drives' frames take {t * 1e3:.2f} ms, more "
                             f"than the control period ({plant.dt * 1e3:g} ms)")
        self.slots = tuple(slots)
        self._fills = fills
        self._angle = np.zeros(len(self.nodes))  # running shaft angles (rad), per drive

    def _value(self, chunk: SimChunk, i: int, source: object) -> np.ndarray:
        if isinstance(source, tuple) and source[0] == "angle":
            omega = source_values(chunk, self.plant, ("z", source[1]))
            return self._angle[i] + np.cumsum(omega) * self.plant.dt
        return source_values(chunk, self.plant, source)

    def encode(self, chunks: Sequence[SimChunk]) -> tuple[np.ndarray, dict[str, int]]:
        n = len(chunks[0])
        data = np.zeros((n, len(self.slots), 8), dtype=np.uint8)
        clipped: dict[str, int] = {}
        ends = self._angle.copy()
        for j, fill in enumerate(self._fills):
            if fill is None:
                continue
            values = []
            for field, source in fill.fields:
                v = self._value(chunks[fill.drive], fill.drive, source)
                if isinstance(source, tuple) and source[0] == "angle" and n:
                    ends[fill.drive] = v[-1]
                values.append((field, v))
            data[:, j] = pack(values, n, clipped, prefix=f"{self.slots[j].name}.")
        self._angle = ends
        return data, clipped


class FloatNodeProfile(BusProfile):
    name = "float_node"
    summary = ("node-ID float protocol (ODrive-like): ID node << 5 | cmd, float32 setpoints and "
               "estimates, currents polled by RTR; no CRC, no counter")
    nodes = (0, 62)
    default_node = 0
    has_crc = False

    def dbc(self, plant: str) -> str | None:
        return _BUSES[plant].dbc if plant in _BUSES else None

    def encoder(self, plant: Plant, nodes: Sequence[int | None],
                frame_spacing: float = 130e-6) -> FloatNodeEncoder:
        if plant.name not in _BUSES:
            raise ValueError(f"the float_node profile does not cover plant {plant.name!r}")
        return FloatNodeEncoder(plant, check_nodes(nodes, self.nodes), frame_spacing,
                                _BUSES[plant.name])
