"""Unit tests of canfdi.firmware_sim, the drive emulator: a file per module or topic."""
