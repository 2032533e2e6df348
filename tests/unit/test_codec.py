"""Precompiled layouts encode and decode exactly like cantools, a block of frames at a time."""

import numpy as np
import pytest

from canfdi import dbc as dbc_files
from canfdi.bus.codec import compile_layout


def _messages():
    for name in dbc_files.available():
        for message in dbc_files.load(name).messages:
            yield pytest.param(name, message.name, id=f"{name}:{message.name}")


def _random_values(layout, rng, n):
    values = {}
    for sig in layout.signals:
        if sig.is_float:
            values[sig.name] = rng.normal(scale=1e3, size=n).astype(np.float32).astype(float)
        else:
            lo, hi = sig.raw_limits()
            raw = rng.integers(lo, hi, size=n, endpoint=True)
            values[sig.name] = raw * sig.scale + sig.offset
            lo_p, hi_p = sig.physical_limits()
            values[sig.name] = np.clip(values[sig.name], lo_p, hi_p)
    return values


@pytest.mark.parametrize(("dbc", "message_name"), list(_messages()))
def test_layout_matches_cantools(dbc, message_name):
    message = dbc_files.load(dbc).get_message_by_name(message_name)
    layout = compile_layout(message)
    rng = np.random.default_rng(abs(hash(message_name)) % 2**32)
    n = 200
    values = _random_values(layout, rng, n)
    payloads, clipped = layout.encode(values, n)
    assert clipped == {}
    assert payloads.shape == (n, message.length)
    decoded = layout.decode(payloads)
    for i in range(0, n, 7):
        row = {k: float(v[i]) for k, v in values.items()}
        want = message.encode(row, scaling=True, strict=False)
        assert payloads[i].tobytes() == want, (message_name, i)
        ref = message.decode(want, decode_choices=False, scaling=True)
        for name, value in ref.items():
            assert decoded[name][i] == pytest.approx(value, rel=1e-12, abs=1e-9), name


def test_out_of_range_values_are_clipped_and_counted():
    message = dbc_files.load("motor_drive").get_message_by_name("DRIVE_CURRENTS")
    layout = compile_layout(message)
    payloads, clipped = layout.encode({"i_f": np.array([1.0, 50.0, -50.0, np.nan])}, 4)
    assert clipped == {"i_f": 3}
    np.testing.assert_allclose(layout.decode(payloads)["i_f"], [1.0, 32.767, -32.768, 0.0])


def test_a_signal_outside_the_payload_is_refused_by_name():
    import cantools

    sig = cantools.database.can.Signal("Speed", start=7, length=16, byte_order="big_endian")
    msg = cantools.database.can.Message(frame_id=1, name="M", length=1, signals=[sig],
                                        strict=False)
    with pytest.raises(ValueError, match=r"M\.Speed"):
        compile_layout(msg)
