"""The plants of the papers, by scenario name."""

from __future__ import annotations

from firmware_sim.plants.base import Controller, NoiseDefaults, Plant

__all__ = ["PLANTS", "Controller", "NoiseDefaults", "Plant", "make_plant"]


def _dc_motor() -> Plant:
    from firmware_sim.plants.dc_motor import DcMotor

    return DcMotor()


def _winding_machine() -> Plant:
    from firmware_sim.plants.winding_machine import WindingMachine

    return WindingMachine()


def _vtol() -> Plant:
    from firmware_sim.plants.vtol import Vtol

    return Vtol()


PLANTS = {"dc_motor": _dc_motor, "winding_machine": _winding_machine, "vtol": _vtol}


def make_plant(name: str) -> Plant:
    """A fresh plant by its scenario name (dc_motor, winding_machine, vtol)."""
    try:
        return PLANTS[name]()
    except KeyError:
        raise ValueError(f"unknown plant {name!r} (known: {', '.join(PLANTS)})") from None
