"""Precompiled DBC message layouts: many frames encoded or decoded per numpy call.

cantools' Message.encode/decode handle one frame at a time through dictionaries. A drive sends
the same few messages every period, so each message's signals are compiled once into
(shift, mask, signed, scale, offset) and whole blocks of frames become 64-bit integer arithmetic:
a classic CAN payload is at most 8 bytes, i.e. one little-endian uint64 per frame.

Supported: Intel (little-endian) integer and IEEE float32 signals in payloads of up to 8 bytes,
which is what canfdi's DBC files use (dbc/README.md). A Motorola (big-endian) or float64 signal
is rejected when the layout is compiled, with the message and signal named.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["MessageLayout", "SignalLayout", "compile_layout"]


@dataclass(frozen=True)
class SignalLayout:
    """One signal's place in the payload and its scaling."""

    name: str
    start: int
    length: int
    signed: bool
    is_float: bool
    scale: float
    offset: float
    minimum: float | None
    maximum: float | None

    @property
    def mask(self) -> int:
        return (1 << self.length) - 1

    def raw_limits(self) -> tuple[int, int]:
        """Representable raw integer range."""
        if self.signed:
            return -(1 << (self.length - 1)), (1 << (self.length - 1)) - 1
        return 0, (1 << self.length) - 1

    def quantize(self, values: np.ndarray) -> np.ndarray:
        """Values as the receiver decodes them after a sender encodes them: clipped to the
        signal's range and rounded to its resolution (float32 for a float signal); the
        arithmetic of `MessageLayout.encode` then `decode`, without building payloads."""
        v = np.asarray(values, dtype=float)
        if self.is_float:
            return v.astype(np.float32).astype(np.float64)
        lo, hi = self.physical_limits()
        v = np.clip(np.nan_to_num(v, nan=0.0), lo, hi)
        return np.rint((v - self.offset) / self.scale) * self.scale + self.offset

    def physical_limits(self) -> tuple[float, float]:
        """The range a value can take without clipping: the DBC's min/max within the raw range."""
        lo_raw, hi_raw = self.raw_limits()
        a, b = lo_raw * self.scale + self.offset, hi_raw * self.scale + self.offset
        lo, hi = min(a, b), max(a, b)
        if self.minimum is not None:
            lo = max(lo, self.minimum)
        if self.maximum is not None:
            hi = min(hi, self.maximum)
        return lo, hi


@dataclass(frozen=True)
class MessageLayout:
    """A compiled message: ID, DLC and its signals, with block encode and decode."""

    name: str
    frame_id: int
    dlc: int
    signals: tuple[SignalLayout, ...]
    senders: tuple[str, ...]

    def signal(self, name: str) -> SignalLayout:
        for sig in self.signals:
            if sig.name == name:
                return sig
        raise KeyError(f"{self.name} has no signal {name!r}")

    def encode(self, values: dict[str, np.ndarray], count: int
               ) -> tuple[np.ndarray, dict[str, int]]:
        """Encode ``count`` frames.

        Parameters
        ----------
        values : signal name -> (count,) physical values; missing signals are encoded as 0.
        count : number of frames.

        Returns
        -------
        payloads : (count, dlc) uint8.
        clipped : signal name -> number of values clipped to the signal's range.
        """
        word = np.zeros(count, dtype=np.uint64)
        clipped: dict[str, int] = {}
        for sig in self.signals:
            if sig.name not in values:
                continue
            v = np.asarray(values[sig.name], dtype=float).reshape(count)
            if sig.is_float:
                raw = v.astype("<f4").view("<u4").astype(np.uint64)
            else:
                lo, hi = sig.physical_limits()
                outside = (v < lo) | (v > hi) | ~np.isfinite(v)
                if outside.any():
                    clipped[sig.name] = int(outside.sum())
                    v = np.clip(np.nan_to_num(v, nan=0.0), lo, hi)
                ints = np.rint((v - sig.offset) / sig.scale).astype(np.int64)
                raw = (ints & sig.mask).astype(np.uint64)
            word |= raw << np.uint64(sig.start)
        payload = word.astype("<u8").view(np.uint8).reshape(count, 8)[:, : self.dlc]
        return np.ascontiguousarray(payload), clipped

    def decode(self, payloads: np.ndarray) -> dict[str, np.ndarray]:
        """Decode (N, L) uint8 payloads (L >= dlc) into signal name -> (N,) float64 values."""
        payloads = np.asarray(payloads, dtype=np.uint8)
        padded = np.zeros((payloads.shape[0], 8), dtype=np.uint8)
        width = min(payloads.shape[1], 8)
        padded[:, :width] = payloads[:, :width]
        word = padded.view("<u8").reshape(-1)
        out = {}
        for sig in self.signals:
            raw = (word >> np.uint64(sig.start)) & np.uint64(sig.mask)
            if sig.is_float:
                out[sig.name] = raw.astype(np.uint32).view("<f4").astype(np.float64)
                continue
            ints = raw.astype(np.int64)
            if sig.signed:
                sign = np.int64(1 << (sig.length - 1))
                ints = np.where(ints & sign, ints - (sign << np.int64(1)), ints)
            out[sig.name] = ints * sig.scale + sig.offset
        return out


def compile_layout(message) -> MessageLayout:
    """Compile a cantools Message; raises ValueError naming an unsupported signal."""
    if message.length > 8:
        raise ValueError(f"{message.name}: payloads over 8 bytes are not supported")
    signals = []
    for sig in message.signals:
        if sig.byte_order != "little_endian":
            raise ValueError(f"{message.name}.{sig.name}: only Intel (little-endian) signals are "
                             "supported by canfdi's precompiled layouts")
        if sig.is_float and sig.length != 32:
            raise ValueError(f"{message.name}.{sig.name}: only float32 signals are supported")
        if sig.start + sig.length > 64:
            raise ValueError(f"{message.name}.{sig.name}: does not fit in 8 bytes")
        signals.append(SignalLayout(
            name=sig.name, start=sig.start, length=sig.length, signed=sig.is_signed,
            is_float=sig.is_float, scale=float(sig.scale), offset=float(sig.offset),
            minimum=None if sig.minimum is None else float(sig.minimum),
            maximum=None if sig.maximum is None else float(sig.maximum),
        ))
    return MessageLayout(name=message.name, frame_id=message.frame_id, dlc=message.length,
                         signals=tuple(signals), senders=tuple(message.senders or ()))
