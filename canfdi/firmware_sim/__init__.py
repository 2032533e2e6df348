"""canfdi.firmware_sim: the plant emulator that plays a motor drive on a CAN bus."""
