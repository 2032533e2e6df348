"""Unit tests of canfdi.bus, the bus layer: a file per module or topic."""
