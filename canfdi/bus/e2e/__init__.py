"""End-to-end (E2E) protection of CAN payloads: the profile registry, one profile per message.

A receiver checks each frame of a protected message and reads its alive counter; a sender (the
emulator, the monitor's own frames) writes both. How is the message's *profile*:

=================  =======================================================================
name               protection
=================  =======================================================================
``none``           none: every frame passes, no counter
``counter``        an alive counter in a named signal, no CRC
``canfdi``         canfdi's own CRC-8 SAE J1850 + 8-bit counter header (``dbc/README.md``)
``autosar_p01``    AUTOSAR E2E Profile 1: CRC-8 SAE J1850 over the Data ID and the data,
                   4-bit counter 0..14
``autosar_p02``    AUTOSAR E2E Profile 2: CRC-8H2F over the data and DataIDList[counter],
                   4-bit counter 0..15
=================  =======================================================================

Every profile satisfies `E2EProfile`: ``check`` and ``counter`` for one payload,
``check_batch``, ``counters`` and ``protect_batch`` for a block of them, the two forms equal.
`make_profile` builds one from what the user wrote in the config for one message (a name, or a
mapping ``{profile: <name>, <option>: <value>, ...}``); `PROFILES` maps each name to its
factory and is the only place that branches on a profile's name. A new profile is one class
with a ``from_config`` classmethod (a module of this package) and one line in `PROFILES`.

=================  ==================================================================
module             holds
=================  ==================================================================
``base``           `E2EProfile` (the protocol), `SignalPlace`, `ProfileFactory`
``crc``            CRC-8 SAE J1850 and CRC-8H2F, scalar and batch (`crc8`, `crc8h2f`)
``none``           `NoProtection`
``counter``        `AliveCounter`
``canfdi``         `CanfdiProfile` and canfdi's header for any ID (`protect`, `check`,
                   `counter_of`, `counter_delta`, the batch forms, `confusable_ids`)
``autosar_p01``    `AutosarP01`
``autosar_p02``    `AutosarP02`
``bitfield``       `BitField`, a counter or Data ID nibble at any bit of a payload
``payloads``       the checks of a block of payloads, lengths and counters
``cspec``          a profile as the C core's flat tables (``c_spec()``; canfdi/_c/e2e.h)
=================  ==================================================================

The receivers' state machines of the AUTOSAR profiles (MaxDeltaCounterInit, SyncCounterInit,
...) are not here: a profile checks one frame and reads its counter; canfdi judges counter
steps itself (`counter_delta` and the assembler).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from canfdi.bus.e2e.autosar_p01 import AutosarP01
from canfdi.bus.e2e.autosar_p02 import AutosarP02
from canfdi.bus.e2e.base import MAX_ARBITRATION_ID, E2EProfile, ProfileFactory, SignalPlace
from canfdi.bus.e2e.canfdi import (
    UNDETECTED_ID_XORS,
    CanfdiProfile,
    check,
    confusable_ids,
    counter_delta,
    counter_of,
    data_id,
    e2e_check_batch,
    e2e_crc,
    protect,
    protect_batch,
)
from canfdi.bus.e2e.counter import AliveCounter
from canfdi.bus.e2e.crc import (
    CRC8_INIT,
    CRC8_POLY,
    CRC8_XOROUT,
    CRC8H2F_INIT,
    CRC8H2F_POLY,
    CRC8H2F_XOROUT,
    crc8,
    crc8_batch,
    crc8h2f,
)
from canfdi.bus.e2e.none import NoProtection
from canfdi.core.settings import ConfigError, unknown_name

__all__ = [
    "CRC8H2F_INIT",
    "CRC8H2F_POLY",
    "CRC8H2F_XOROUT",
    "CRC8_INIT",
    "CRC8_POLY",
    "CRC8_XOROUT",
    "MAX_ARBITRATION_ID",
    "PROFILES",
    "UNDETECTED_ID_XORS",
    "AliveCounter",
    "AutosarP01",
    "AutosarP02",
    "CanfdiProfile",
    "E2EProfile",
    "NoProtection",
    "ProfileFactory",
    "SignalPlace",
    "check",
    "confusable_ids",
    "counter_delta",
    "counter_of",
    "crc8",
    "crc8_batch",
    "crc8h2f",
    "data_id",
    "e2e_check_batch",
    "e2e_crc",
    "make_profile",
    "protect",
    "protect_batch",
]

# CAN FD's longest payload.
_MAX_PAYLOAD = 64

# The registry: the only place that branches on a profile's name.
PROFILES: dict[str, ProfileFactory] = {
    NoProtection.name: NoProtection.from_config,
    AliveCounter.name: AliveCounter.from_config,
    CanfdiProfile.name: CanfdiProfile.from_config,
    AutosarP01.name: AutosarP01.from_config,
    AutosarP02.name: AutosarP02.from_config,
}


def make_profile(spec: str | Mapping[str, Any], frame_id: int, is_extended: bool, length: int,
                 signals: Mapping[str, SignalPlace], where: str) -> E2EProfile:
    """The E2E profile of one message, from what the user wrote for it in the config.

    Parameters
    ----------
    spec : a profile name (``"none"``), or a mapping with the name under ``profile`` and the
        profile's options beside it (``{profile: counter, signal: Alive, modulus: 16}``).
    frame_id : the message's arbitration ID.
    is_extended : whether it is a 29-bit ID.
    length : the message's length in bytes (DBC), 0..64.
    signals : the message's signal names -> `SignalPlace` ``(start, length, byte_order)``, in
        cantools' conventions (``signal.start``, ``signal.length``, ``signal.byte_order``).
    where : the dotted config path of ``spec`` (``bus.e2e.messages.MotorFeedback``).

    Returns
    -------
    E2EProfile.

    Raises
    ------
    ConfigError
        ``where`` (or ``where.profile``) for an unknown profile name, listing the known ones and
        the nearest; ``where.<key>`` for a bad option.

    Examples
    --------
    >>> make_profile({"profile": "autosar_p1"}, 0x10, False, 8, {}, "bus.e2e.messages.M")
    Traceback (most recent call last):
    ...
    canfdi.core.settings.ConfigError: bus.e2e.messages.M.profile: unknown E2E profile \
'autosar_p1' (did you mean autosar_p01 or autosar_p02? known: autosar_p01, autosar_p02, canfdi, \
counter, none)
    """
    if not 0 <= length <= _MAX_PAYLOAD:
        raise ValueError(f"length must be in 0..{_MAX_PAYLOAD} bytes, got {length}")
    if frame_id < 0 or frame_id > (0x1FFFFFFF if is_extended else MAX_ARBITRATION_ID):
        raise ValueError(f"frame_id {frame_id:#x} is not a {29 if is_extended else 11}-bit ID")
    if isinstance(spec, str):
        name, options, name_field = spec, {}, where
    elif isinstance(spec, Mapping):
        name_field = f"{where}.profile"
        if "profile" not in spec:
            raise ConfigError(name_field, f"missing: name the E2E profile (known: "
                                          f"{', '.join(sorted(PROFILES))})")
        name = spec["profile"]
        options = {key: value for key, value in spec.items() if key != "profile"}
    else:
        raise ConfigError(where, f"expected an E2E profile name or a mapping with 'profile' "
                                 f"and its options, got {type(spec).__name__}")
    if not isinstance(name, str) or name not in PROFILES:
        raise unknown_name(name_field, "E2E profile", name, PROFILES)
    return PROFILES[name](options, frame_id, is_extended, length, signals, where)
