"""Unit tests of canfdi.io, the log I/O layer: a file per module or topic."""
