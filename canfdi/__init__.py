"""canfdi: model-based fault detection, isolation and identification on CAN buses."""

__version__ = "0.1.0"
