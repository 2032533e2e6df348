"""Bus profiles of the emulator: the ways a drive talks on the bus, by the scenario's name.

=========== ===========================================================================
name        bus
=========== ===========================================================================
canfdi      canfdi's own DBCs: CRC-8 + alive counter in every drive frame (default)
cia402      CANopen CiA 402 drive(s) and master: SYNC, RPDO, TPDOs, heartbeat
float_node  node-ID float protocol (ODrive-like): node << 5 | cmd, float32, RTR polls
=========== ===========================================================================

This registry is the only place that branches on a profile's name; everything else asks the
profile (`BusProfile`: its DBC per plant, its node IDs, whether it has a CRC, its encoder).
A new profile is one module here and one line below (canfdi/firmware_sim/profiles/base.py says what
it provides).

Examples
--------
>>> sorted(PROFILES)
['canfdi', 'cia402', 'float_node']
>>> get_profile("cia402").dbc("dc_motor")
'dc_motor_cia402'
"""

from __future__ import annotations

import difflib

from canfdi.firmware_sim.profiles.base import BusEncoder, BusProfile, Slot
from canfdi.firmware_sim.profiles.canfdi import CanfdiProfile
from canfdi.firmware_sim.profiles.cia402 import Cia402Profile
from canfdi.firmware_sim.profiles.float_node import FloatNodeProfile

__all__ = ["DEFAULT_PROFILE", "PROFILES", "BusEncoder", "BusProfile", "Slot", "get_profile"]

PROFILES: dict[str, BusProfile] = {
    "canfdi": CanfdiProfile(),
    "cia402": Cia402Profile(),
    "float_node": FloatNodeProfile(),
}
DEFAULT_PROFILE = "canfdi"


def get_profile(name: str) -> BusProfile:
    """The profile called ``name``; a ValueError lists the nearest names that exist."""
    try:
        return PROFILES[name]
    except (KeyError, TypeError):
        near = difflib.get_close_matches(str(name), PROFILES, n=3)
        hint = f"did you mean {', '.join(near)}? " if near else ""
        raise ValueError(f"unknown bus profile {name!r} ({hint}known: "
                       f"{', '.join(PROFILES)})") from None
