"""The systemd units in deploy/systemd: one hardening block, the template's per-bus command.

canfdi.service (one bus), canfdi@.service (one monitor per bus, instance = interface) and
canfdi-sim.service carry the same hardening block, written out in each file (a unit cannot
include another), so this test is what keeps them from drifting. systemd itself checks the
units in tests/vcan/test_systemd_units.py (systemd-analyze verify and security).
"""

from __future__ import annotations

import shlex
from pathlib import Path

import pytest

from tests.cli import canfdi_parser as build_parser
from tests.conftest import REPO

UNITS = REPO / "deploy" / "systemd"
MONITOR, TEMPLATE, SIM = "canfdi.service", "canfdi@.service", "canfdi-sim.service"
BEGIN, END = "# --- hardening:", "# --- end of hardening"

Entry = tuple[str, str, str]  # (section, key, value)


def parse_unit(text: str) -> list[Entry]:
    """A unit file's assignments in order (systemd syntax: sections, '#'/';' comments,
    repeated keys kept: SystemCallFilter= and WantedBy= may appear twice)."""
    entries: list[Entry] = []
    section = ""
    for line in text.splitlines():
        line = line.strip()
        if not line or line[0] in "#;":
            continue
        if line.startswith("[") and line.endswith("]"):
            section = line[1:-1]
            continue
        key, sep, value = line.partition("=")
        assert sep, f"not an assignment: {line!r}"
        entries.append((section, key.strip(), value.strip()))
    return entries


def hardening_block(text: str) -> str:
    """The text between the hardening markers (the markers' lines included)."""
    start, end = text.find(BEGIN), text.find(END)
    assert 0 <= start < end, "the hardening markers are missing or out of order"
    return text[start:text.index("\n", end)]


def read(name: str) -> str:
    return (UNITS / name).read_text()


def service(name: str) -> list[tuple[str, str]]:
    return [(k, v) for s, k, v in parse_unit(read(name)) if s == "Service"]


def instantiate(value: str, instance: str) -> str:
    """systemd's specifiers %i (escaped instance), %I (unescaped) and %% in a value."""
    out, i = [], 0
    while i < len(value):
        if value[i] == "%" and i + 1 < len(value):
            spec = value[i + 1]
            assert spec in "iI%", f"specifier %{spec} not expected in {value!r}"
            out.append("%" if spec == "%" else instance)
            i += 2
        else:
            out.append(value[i])
            i += 1
    return "".join(out)


def exec_args(name: str, program: str) -> list[str]:
    """ExecStart's arguments after ``program`` (its path is checked to be /opt/canfdi's)."""
    [command] = [v for k, v in service(name) if k == "ExecStart"]
    argv = shlex.split(command)
    assert argv[0] == f"/opt/canfdi/.venv/bin/{program}", argv[0]
    return argv[1:]


def test_the_hardening_block_is_the_same_in_every_unit():
    blocks = {name: hardening_block(read(name)) for name in (MONITOR, TEMPLATE, SIM)}
    assert blocks[TEMPLATE] == blocks[MONITOR]
    assert blocks[SIM] == blocks[MONITOR]


@pytest.mark.parametrize("name", [MONITOR, TEMPLATE, SIM])
def test_no_hardening_key_is_set_again_outside_the_block(name):
    """A later assignment would override (or, for lists, widen) the block's."""
    text = read(name)
    block = hardening_block(text)
    block_keys = {k for _, k, _ in parse_unit("[Service]\n" + block)}
    outside = parse_unit(text.replace(block, ""))
    assert not [k for _, k, _ in outside if k in block_keys]


def test_the_block_keeps_the_original_hardening_and_the_sandbox():
    entries = parse_unit("[Service]\n" + hardening_block(read(MONITOR)))
    values: dict[str, list[str]] = {}
    for _, key, value in entries:
        values.setdefault(key, []).append(value)
    for key, value in {
        # The single unit's hardening before the template (issue 18 keeps it) ...
        "DynamicUser": "yes", "ProtectSystem": "strict", "ProtectHome": "yes",
        "PrivateTmp": "yes", "NoNewPrivileges": "yes",
        # ... and what brought the exposure into systemd's SAFE band.
        "CapabilityBoundingSet": "", "PrivateUsers": "yes", "PrivateDevices": "yes",
        "DevicePolicy": "closed", "MemoryDenyWriteExecute": "yes", "IPAddressDeny": "any",
        "ProtectProc": "invisible", "ProcSubset": "pid", "SystemCallArchitectures": "native",
        "UMask": "0077", "SystemCallErrorNumber": "EPERM",
    }.items():
        assert values.get(key) == [value], key
    # CAN, the notify socket and netlink only: no IP family, whatever the order.
    assert [set(v.split()) for v in values["RestrictAddressFamilies"]] == [
        {"AF_CAN", "AF_UNIX", "AF_NETLINK"}]
    assert values["SystemCallFilter"] == ["@system-service", "~@privileged @resources"]


def test_the_template_and_the_single_unit_run_the_same_service_but_for_the_bus():
    """Type=notify, watchdog, restart policy, environment: identical; only the command line
    and the logs and cache directories name the bus."""
    per_bus = {"ExecStart", "LogsDirectory", "CacheDirectory"}
    single = [(k, v) for k, v in service(MONITOR) if k not in per_bus]
    template = [(k, v) for k, v in service(TEMPLATE) if k not in per_bus]
    assert template == single
    for key, value in [("Type", "notify"), ("NotifyAccess", "main"),
                       ("RestartPreventExitStatus", "2"), ("Restart", "on-failure")]:
        assert (key, value) in template


def test_the_template_runs_the_monitor_on_its_instance():
    """canfdi@can0: /etc/canfdi/can0.yaml on socketcan can0, logs in /var/log/canfdi/can0,
    as canfdi's own argument parser reads the command line."""
    entries = parse_unit(read(TEMPLATE))
    [logs] = [v for s, k, v in entries if k == "LogsDirectory"]
    assert instantiate(logs, "can0") == "canfdi/can0"
    args = [instantiate(a, "can0") for a in exec_args(TEMPLATE, "canfdi")]
    # systemd sets $LOGS_DIRECTORY to LogsDirectory= under /var/log.
    args = [a.replace("${LOGS_DIRECTORY}", "/var/log/canfdi/can0") for a in args]
    parsed = build_parser().parse_args(args)
    assert (parsed.verb, parsed.interface, parsed.channel) == ("run", "socketcan", "can0")
    assert parsed.config == Path("/etc/canfdi/can0.yaml")
    assert parsed.log_dir == Path("/var/log/canfdi/can0")
    assert (parsed.log_format, parsed.quiet, parsed.foxglove) == ("json", True, None)
    # The device unit's name takes the escaped instance (%i), commands the unescaped (%I).
    device = "sys-subsystem-net-devices-%i.device"
    for key in ("BindsTo", "After"):
        assert (("Unit", key, device)) in entries, key
    assert ("Install", "WantedBy", device) in entries
    assert all("%i" not in v for _, k, v in entries if k in ("ExecStart", "LogsDirectory"))


def test_the_single_unit_and_the_emulator_unit_parse_as_canfdi_commands():
    monitor = build_parser().parse_args(exec_args(MONITOR, "canfdi"))
    # The single unit's bus is its config's: no interface or channel on its command line.
    assert (monitor.verb, monitor.interface, monitor.channel) == ("run", None, None)
    assert "vcan0" not in " ".join(v for _, _, v in parse_unit(
        (UNITS / MONITOR).read_text()))
    assert monitor.log_dir == Path("/var/log/canfdi")
    sim = build_parser().parse_args(["sim", *exec_args(SIM, "canfdi-sim")])
    assert (sim.interface, sim.channel) == ("socketcan", "vcan0")


def test_the_parser_reads_repeated_keys_and_the_instantiation_escapes():
    entries = parse_unit("[Service]\n# c\n; c\nA=1\nA=\nB= x y \n[Install]\nW=%i-%I-%%\n")
    assert entries == [("Service", "A", "1"), ("Service", "A", ""), ("Service", "B", "x y"),
                       ("Install", "W", "%i-%I-%%")]
    assert instantiate(entries[-1][2], "can0") == "can0-can0-%"
