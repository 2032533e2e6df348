"""canfdi's CAN databases, installed as the package ``canfdi.dbc``.

The ``dbc/`` directory of the repository holds the drive's DBC of each emulated plant on
canfdi's own bus, the monitor's own frames (``canfdi_monitor.dbc``: the four ``FDI_*``
messages, at IDs a config may move) and the vendor-style DBCs of the emulator's other bus
profiles (CiA 402, node-id float); ``pyproject.toml`` maps it to ``canfdi.dbc`` so that the
files ship inside the wheel and resolve the same way from a checkout, an editable install and a
regular install. The conventions are in ``README.md`` next to this module.

Examples
--------
>>> import canfdi.dbc
>>> db = canfdi.dbc.load("motor_drive")
>>> hex(db.get_message_by_name("DRIVE_CMD").frame_id)
'0x104'
>>> [hex(m.frame_id) for m in canfdi.dbc.load("canfdi_monitor").messages]
['0x80', '0x81', '0x82', '0x83']
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    # cantools is imported lazily: listing or locating the files should not pay for it.
    from cantools.database.can import Database

__all__ = ["DBC_DIR", "available", "load", "path"]

DBC_DIR = Path(__file__).resolve().parent
_SUFFIX = ".dbc"


def available() -> list[str]:
    """Names of the DBC files shipped with canfdi.

    Returns
    -------
    list of str, sorted, without the ``.dbc`` suffix (e.g. ``["motor_drive", ...]``).
    """
    return sorted(p.stem for p in DBC_DIR.glob(f"*{_SUFFIX}") if p.is_file())


def path(name: str) -> Path:
    """Location of a shipped DBC file.

    Parameters
    ----------
    name : file name with or without the suffix: ``"motor_drive"`` or ``"motor_drive.dbc"``.

    Returns
    -------
    Absolute path of the file.

    Raises
    ------
    ValueError
        If name is empty or contains a directory part (only shipped files can be named).
    FileNotFoundError
        If there is no such file; the message lists the available names.
    """
    if not isinstance(name, str) or not name or Path(name).name != name:
        raise ValueError(f"name must be a bare DBC file name such as 'motor_drive', got {name!r}")
    stem = name.removesuffix(_SUFFIX)
    candidate = DBC_DIR / f"{stem}{_SUFFIX}"
    if not candidate.is_file():
        names = ", ".join(available()) or "none"
        raise FileNotFoundError(f"no DBC file {name!r} in {DBC_DIR}; available: {names}")
    return candidate


def load(name: str) -> Database:
    """Load a shipped DBC file with cantools' strict checks.

    Parameters
    ----------
    name : as for `path`.

    Returns
    -------
    cantools.database.can.Database; strict loading rejects overlapping signals and signals that
    do not fit their message.
    """
    import cantools

    db = cantools.database.load_file(path(name), database_format="dbc", strict=True)
    # load_file is typed to return any database kind; a .dbc file always yields a CAN database.
    return db  # type: ignore[return-value]
