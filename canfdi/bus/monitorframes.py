"""The monitor's own frames: FDI_FAULT, FDI_ESTIMATE, FDI_STATUS (and FDI_RESIDUAL).

Their layout comes from a DBC (``bus.monitor.dbc``, default the shipped canfdi_monitor.dbc),
their IDs from the config (``bus.monitor.base`` or ``ids``; default the DBC's), their E2E
profile from ``bus.monitor.e2e`` (default canfdi). An ID that collides with a message of the
drives' DBC (after the node-id template), or on a CANopen bus (``bus.canopen: true``) with one
of CANopen's predefined function codes, is refused, naming the IDs: a monitor that transmits
there would disturb the whole bus.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping

import numpy as np

from canfdi.bus.codec import MessageLayout, compile_layout
from canfdi.bus.dbc import Known, MessageKey, find_message, load_dbc, message_key
from canfdi.bus.e2e import E2EProfile, confusable_ids, make_profile
from canfdi.core.settings import ConfigError, MonitorConfig

__all__ = ["CANOPEN_FUNCTION_CODES", "MONITOR_MESSAGES", "MonitorFrames"]

MONITOR_MESSAGES = ("FDI_FAULT", "FDI_ESTIMATE", "FDI_STATUS", "FDI_RESIDUAL")
"""The monitor's messages, in the order ``bus.monitor.base`` numbers them."""

# CiA 301's predefined connection set (11-bit IDs): what each range is for.
CANOPEN_FUNCTION_CODES = (
    (0x000, 0x000, "NMT"), (0x080, 0x080, "SYNC"), (0x081, 0x0FF, "EMCY"),
    (0x100, 0x100, "TIME"), (0x181, 0x1FF, "TPDO1"), (0x201, 0x27F, "RPDO1"),
    (0x281, 0x2FF, "TPDO2"), (0x301, 0x37F, "RPDO2"), (0x381, 0x3FF, "TPDO3"),
    (0x401, 0x47F, "RPDO3"), (0x481, 0x4FF, "TPDO4"), (0x501, 0x57F, "RPDO4"),
    (0x581, 0x5FF, "SDO (tx)"), (0x601, 0x67F, "SDO (rx)"), (0x701, 0x77F, "NMT heartbeat"),
    (0x7E4, 0x7E5, "LSS"),
)


def _canopen_use(frame_id: int) -> str | None:
    for lo, hi, what in CANOPEN_FUNCTION_CODES:
        if lo <= frame_id <= hi:
            return what
    return None


class MonitorFrames:
    """The monitor's frames on this bus: encode them with their IDs and E2E.

    Attributes
    ----------
    layouts : message name -> compiled layout (the monitor DBC's).
    keys : message name -> (ID, extended) on this bus.
    transmit : False for a listen-only monitor (`encode` gives nothing).

    Examples
    --------
    The shipped dc_motor config's monitor frames (the DBC's IDs, canfdi's CRC and counter):

    >>> from canfdi.bus.dbc import BusMap
    >>> from canfdi.bus.e2e import check
    >>> from canfdi.core.settings import BusConfig, MonitorConfig
    >>> config = MonitorConfig.of_bus("dc_motor", ["V"], ["i_f", "i_a", "i_f_plus_i_a", "omega_r"],
    ...                               BusConfig(dbc="motor_drive"))
    >>> frames = MonitorFrames.from_config(config, BusMap.from_config(config).keys)
    >>> frames.keys["FDI_STATUS"]
    (130, False)
    >>> (frame_id, _), payload = frames.encode("FDI_STATUS", {"Samples": 100})
    >>> frame_id, payload[1], check(frame_id, payload)
    (130, 0, True)
    >>> frames.known()[(130, False)].kind
    'monitor'
    """

    def __init__(self, layouts: Mapping[str, MessageLayout], keys: Mapping[str, MessageKey],
                 profiles: Mapping[str, E2EProfile], transmit: bool = True) -> None:
        self.layouts = dict(layouts)
        self.keys = dict(keys)
        self._profiles = dict(profiles)
        self.transmit = transmit
        self._counters = dict.fromkeys(self.layouts, 0)

    @classmethod
    def from_config(cls, config: MonitorConfig, bus_keys: Iterable[MessageKey]
                    ) -> MonitorFrames:
        """The monitor frames of ``config.bus.monitor``, checked against the IDs the drives'
        messages have on this bus (``bus_keys``)."""
        mon = config.bus.monitor
        database, label = load_dbc(mon.dbc, config.path, "bus.monitor.dbc")
        for name in mon.ids:
            if name not in MONITOR_MESSAGES:
                from canfdi.core.settings import unknown_name

                raise unknown_name(f"bus.monitor.ids.{name}", "monitor message", name,
                                   MONITOR_MESSAGES)
        layouts, keys, profiles = {}, {}, {}
        for i, name in enumerate(MONITOR_MESSAGES):
            message = find_message(database, name, "bus.monitor.dbc", label)
            fid = (mon.ids.get(name) if name in mon.ids
                   else mon.base + i if mon.base is not None else message.frame_id)
            key = message_key(fid, message.is_extended_frame or fid > 0x7FF)
            layouts[name] = compile_layout(message)
            keys[name] = key
            places = {s.name: (s.start, s.length, s.byte_order) for s in message.signals}
            profiles[name] = make_profile(mon.e2e, key[0], key[1], message.length, places,
                                          "bus.monitor.e2e")
        _check_collisions(keys, set(bus_keys), config.bus.canopen)
        e2e = config.bus.e2e
        if _names_canfdi(mon.e2e) and (_names_canfdi(e2e.default) or any(
                _names_canfdi(spec) for spec in e2e.messages.values())):
            _check_confusable(keys, set(bus_keys))
        return cls(layouts, keys, profiles, config.bus.transmit)

    def known(self) -> dict[MessageKey, Known]:
        """The monitor's messages as a drive's BusMap knows them (status "monitor", checked
        for length and E2E)."""
        return {self.keys[name]: Known("monitor", layout.dlc, False, self._profiles[name])
                for name, layout in self.layouts.items()}

    def profile(self, name: str) -> E2EProfile:
        """The E2E profile of monitor message ``name``."""
        return self._profiles[name]

    def encode(self, name: str, values: Mapping[str, float]) -> tuple[MessageKey, bytes] | None:
        """The frame of one monitor message with those signal values (E2E applied), or None
        when listen-only."""
        if not self.transmit:
            return None
        layout = self.layouts[name]
        payload, _ = layout.encode({k: np.array([v]) for k, v in values.items()}, 1)
        counter = self._counters[name]
        self._counters[name] = counter + 1
        protected = self._profiles[name].protect_batch(payload, np.array([counter]))
        return self.keys[name], protected[0].tobytes()


def _names_canfdi(spec: object) -> bool:
    """Whether an E2E spec (a name or ``{profile: ...}``) is canfdi's CRC-8 + counter."""
    return (spec.get("profile") if isinstance(spec, Mapping) else spec) == "canfdi"


def _check_confusable(keys: Mapping[str, MessageKey], bus_keys: set[MessageKey]) -> None:
    """canfdi's 8-bit CRC cannot tell some pairs of 11-bit IDs apart (dbc/README.md, Blind
    spots): a monitor ID must not pair so with an ID of the bus when both carry it."""
    ours = {key[0]: name for name, key in keys.items() if not key[1]}
    theirs = {key[0] for key in bus_keys if not key[1]}
    pairs = [(a, b) for a, b in confusable_ids(sorted(set(ours) | theirs))
             if (a in ours) != (b in ours)]
    if pairs:
        listed = ", ".join(f"{ours.get(a) or ours.get(b)} 0x{a if a in ours else b:X} with "
                           f"0x{b if a in ours else a:X}" for a, b in pairs)
        raise ConfigError("bus.monitor", f"under canfdi's CRC-8 the monitor's IDs cannot be "
                                         f"told apart from the bus's: {listed}; choose others "
                                         "(bus.monitor.base or bus.monitor.ids)")


def _check_collisions(keys: Mapping[str, MessageKey], bus_keys: set[MessageKey],
                      canopen: bool) -> None:
    clashes = [f"{name} 0x{key[0]:X}" for name, key in keys.items() if key in bus_keys]
    if clashes:
        raise ConfigError("bus.monitor", f"the monitor's frames would use IDs of the drives' "
                                         f"messages: {', '.join(clashes)}; choose others "
                                         "(bus.monitor.base or bus.monitor.ids)")
    if len(set(keys.values())) != len(keys):
        raise ConfigError("bus.monitor.ids", "two monitor messages share an ID")
    if canopen:
        used = [f"{name} 0x{key[0]:X} ({_canopen_use(key[0])})" for name, key in keys.items()
                if not key[1] and _canopen_use(key[0])]
        if used:
            raise ConfigError("bus.monitor", f"on a CANopen bus these IDs are CANopen's: "
                                             f"{', '.join(used)}; choose IDs outside its "
                                             "predefined connection set (e.g. 0x6E0)")


def monitor_database(config: MonitorConfig, merge: bool = False):
    """The DBC of the monitor's frames as ``config`` sends them (a cantools Database): the
    monitor DBC's messages at the config's IDs (``bus.monitor.base``/``ids``, standard or
    extended), each message's comment naming its E2E profile (``bus.monitor.e2e``). With
    ``merge``, they are added to a copy of the bus's DBC (the drives' messages as written
    there) and its node list gains the monitor's. ConfigError when a message of the bus's DBC
    has a monitor message's ID (a decoder could not tell them apart)."""
    import copy

    from canfdi.bus.dbc import keys_of

    database, label = load_dbc(config.bus.dbc, config.path)
    frames = MonitorFrames.from_config(config, keys_of(database, config))
    monitor_db, _ = load_dbc(config.bus.monitor.dbc, config.path, "bus.monitor.dbc")
    monitor_db = copy.deepcopy(monitor_db)  # the shipped ones are shared, cached
    ours = []
    for name in MONITOR_MESSAGES:
        message = monitor_db.get_message_by_name(name)
        message.frame_id, message.is_extended_frame = frames.keys[name]
        profile = frames._profiles[name].name
        said = f"E2E profile {profile} (bus.monitor.e2e)."
        message.comment = f"{message.comment} {said}" if message.comment else said
        ours.append(message)
    if not merge:
        monitor_db.refresh()
        return monitor_db
    merged = copy.deepcopy(database)
    taken = {message_key(m.frame_id, m.is_extended_frame): m.name for m in merged.messages}
    clashes = [f"{m.name} 0x{m.frame_id:X} with {taken[key]}" for m in ours
               if (key := message_key(m.frame_id, m.is_extended_frame)) in taken]
    if clashes:
        raise ConfigError("bus.monitor", f"{label} has messages at the monitor's IDs: "
                                         f"{', '.join(clashes)}; choose others "
                                         "(bus.monitor.base or bus.monitor.ids)")
    merged.messages.extend(ours)
    have = {node.name for node in merged.nodes}
    merged.nodes.extend(node for node in monitor_db.nodes if node.name not in have)
    merged.refresh()
    return merged
