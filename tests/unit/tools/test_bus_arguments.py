"""The bus as python-can users configure it (issue 28): -i/-c/-b, --fd, --data-bitrate,
--bus-kwargs, and python-can's own configuration, by one precedence: the command line, then the
config file's bus: section (what it states), then python-can's configuration, then canfdi's
defaults."""

from __future__ import annotations

import pytest

from canfdi.config import parse_config
from canfdi.tools.session import BusArgumentError, bus_kwargs, bus_settings, python_can_config
from tests.cli import run_bus_request
from tests.conftest import REPO

CONFIG = REPO / "deploy" / "config" / "dc_motor.yaml"


def _args(*argv: str):
    return run_bus_request(*argv)


def _bus(text: str):
    import yaml

    return parse_config(yaml.safe_load(text), CONFIG).bus


@pytest.fixture
def no_python_can_config(monkeypatch, tmp_path):
    for name in ("CAN_INTERFACE", "CAN_CHANNEL", "CAN_BITRATE", "CAN_CONFIG"):
        monkeypatch.delenv(name, raising=False)
    monkeypatch.setenv("HOME", str(tmp_path))  # no ~/can.conf
    monkeypatch.chdir(tmp_path)  # no ./can.ini
    import can.util

    monkeypatch.setattr(can.util, "CONFIG_FILES", [str(tmp_path / "can.ini")])


def test_the_command_line_wins_then_the_config_then_python_can(monkeypatch,
                                                                no_python_can_config):
    text = CONFIG.read_text()
    assert "  interface: virtual" in text and "  channel: canfdi" in text
    stated = _bus(text)
    silent = _bus(text.replace("  interface: virtual", "").replace("  channel: canfdi", ""))
    assert stated.stated == {"interface", "channel"} and silent.stated == frozenset()
    assert bus_settings(_args(), silent) == ("virtual", "canfdi", None)  # canfdi's defaults
    monkeypatch.setenv("CAN_INTERFACE", "virtual")
    monkeypatch.setenv("CAN_CHANNEL", "from-env")
    monkeypatch.setenv("CAN_BITRATE", "250000")
    assert python_can_config()["channel"] == "from-env"
    assert bus_settings(_args(), silent) == ("virtual", "from-env", 250000)
    assert bus_settings(_args(), stated) == ("virtual", "canfdi", 250000)  # the file says
    assert bus_settings(_args("-i", "socketcan", "-c", "vcan0", "-b", "500000"), stated) == (
        "socketcan", "vcan0", 500000)
    assert bus_settings(_args("--channel", "x"), None) == ("virtual", "x", 250000)


def test_fd_and_bus_kwargs_become_keyword_arguments():
    args = _args("--fd", "--data-bitrate", "2000000", "--bus-kwargs", "receive_own_messages=true",
                 "poll_interval=0.5", "serial=ABC", "empty=")
    assert bus_kwargs(args) == {"fd": True, "data_bitrate": 2_000_000,
                                "receive_own_messages": True, "poll_interval": 0.5,
                                "serial": "ABC", "empty": ""}
    assert bus_kwargs(_args()) == {}
    for bad in ("novalue", "=1", "not an id=2"):
        with pytest.raises(BusArgumentError, match="KEY=VALUE"):
            bus_kwargs(_args("--bus-kwargs", bad))


def test_a_bad_bus_kwargs_is_one_line_and_exit_2(capsys):
    from tests.cli import canfdi_main as main

    assert main(["run", "--config", str(CONFIG), "--no-record", "--bus-kwargs", "oops"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["canfdi run: --bus-kwargs: expected KEY=VALUE, got 'oops'"]
