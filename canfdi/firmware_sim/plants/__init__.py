"""The emulated plants, by scenario name.

A plant may take options (a scenario's ``plant_options``): ``make_plant(name, options)`` passes
them to the plant's constructor; a plant without options refuses any. A bad option raises
`PlantOptionError`, a ValueError whose ``option`` names it.

Examples
--------
>>> make_plant("servo_axis", {"reference": "commissioning"}).reference
'commissioning'
>>> make_plant("dc_motor", {"load": False})
Traceback (most recent call last):
...
canfdi.firmware_sim.plants.base.PlantOptionError: load: not an option of plant dc_motor \
(it takes none)
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any

from canfdi.firmware_sim.plants.base import Controller, NoiseDefaults, Plant, PlantOptionError

__all__ = ["PLANTS", "Controller", "NoiseDefaults", "Plant", "PlantOptionError", "make_plant"]


def _no_options(name: str, options: Mapping[str, Any]) -> None:
    if options:
        key = next(iter(options))
        raise PlantOptionError(key, f"not an option of plant {name} (it takes none)")


def _dc_motor(**options: Any) -> Plant:
    from canfdi.firmware_sim.plants.dc_motor import DcMotor

    _no_options("dc_motor", options)
    return DcMotor()


def _winding_machine(**options: Any) -> Plant:
    from canfdi.firmware_sim.plants.winding_machine import WindingMachine

    _no_options("winding_machine", options)
    return WindingMachine()


def _vtol(**options: Any) -> Plant:
    from canfdi.firmware_sim.plants.vtol import Vtol

    _no_options("vtol", options)
    return Vtol()


def _servo_axis(**options: Any) -> Plant:
    from canfdi.firmware_sim.plants.servo_axis import OPTIONS, ServoAxis

    for key in options:
        if key not in OPTIONS:
            raise PlantOptionError(key, f"not an option of plant servo_axis (allowed: "
                                             f"{', '.join(OPTIONS)})")
    return ServoAxis(**options)


PLANTS: dict[str, Callable[..., Plant]] = {
    "dc_motor": _dc_motor,
    "winding_machine": _winding_machine,
    "vtol": _vtol,
    "servo_axis": _servo_axis,
}
"""Scenario name -> factory; ``PLANTS[name]()`` is the plant with its default options."""


def make_plant(name: str, options: Mapping[str, Any] | None = None) -> Plant:
    """A fresh plant by its scenario name (dc_motor, winding_machine, vtol, servo_axis).

    Parameters
    ----------
    name : the scenario's ``plant:``.
    options : the plant's options (``plant_options:``); None or empty: its defaults.

    Raises
    ------
    ValueError : an unknown plant; PlantOptionError (a ValueError) : an option the plant does
        not take or a bad value, naming the option.
    """
    try:
        factory = PLANTS[name]
    except (KeyError, TypeError):
        raise ValueError(f"unknown plant {name!r} (known: {', '.join(PLANTS)})") from None
    options = dict(options or {})
    for key in options:
        if not isinstance(key, str):
            raise PlantOptionError(str(key), f"an option's name is a string, got {key!r}")
    return factory(**options)
