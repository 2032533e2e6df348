"""The pure numerical core: numpy, scipy and the standard library only.

Nothing here touches a bus, a file, a clock or asyncio (an import-linter contract in
pyproject.toml enforces it), so the same code runs live, sample by sample, and offline
over whole arrays.
"""
