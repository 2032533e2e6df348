"""Unit tests of canfdi.core, the numerical core: a file per module or topic."""
