"""canfdi's shipped monitor configs, installed as the package ``canfdi.configs``.

The ``deploy/config/`` directory of the repository holds a monitor config for each emulated
plant and bus profile; ``pyproject.toml`` maps it to ``canfdi.configs`` (as ``dbc/`` is mapped
to ``canfdi.dbc``), so that the verbs that default to one (demo, evaluate, soak, bench) find
them in the wheel as in a checkout. `CONFIG_DIR` is where they are.

Examples
--------
>>> import canfdi.configs
>>> (canfdi.configs.CONFIG_DIR / "dc_motor.yaml").is_file()
True
"""

from __future__ import annotations

from pathlib import Path

__all__ = ["CONFIG_DIR"]

CONFIG_DIR = Path(__file__).resolve().parent
"""The directory of the shipped configs (``deploy/config/`` in a checkout)."""
