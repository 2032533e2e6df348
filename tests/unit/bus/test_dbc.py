"""Every DBC file in dbc/ against the conventions of dbc/README.md, by kind.

The files are globbed, so a new file is checked as soon as it lands:

- plant DBCs of canfdi's own bus (every file that is neither the monitor's DBC nor claimed by a
  bus profile of the emulator other than canfdi): drive messages only, E2E header, IDs no
  monitor default ID can be confused with, the plant's names, the scenarios' ranges;
- canfdi_monitor.dbc, the monitor's own four messages: the README's tables and dbc blocks, and
  round trips through the monitor's own encoder (canfdi.bus.monitorframes);
- the vendor-style DBCs of the other bus profiles (firmware_sim/profiles: cia402, float_node):
  what every DBC here must give (a strict load, comments, cycle times, round trips) and, with
  the monitor configs that read them, their signals' ranges.
"""

from __future__ import annotations

import dataclasses
import re
import subprocess
import sys
import tomllib
from pathlib import Path

import cantools
import numpy as np
import pytest
from cantools.database.can import Database, Message, Signal

from canfdi import dbc as dbc_package
from canfdi.bus import e2e
from canfdi.bus.monitorframes import MONITOR_MESSAGES, MonitorFrames
from canfdi.config import MAX_DRIVES, load_config
from canfdi.core.settings import MonitorFramesConfig

REPO = Path(__file__).resolve().parents[3]
DBC_DIR = REPO / "dbc"
ALL_DBC_FILES = sorted(DBC_DIR.glob("*.dbc"))
README = DBC_DIR / "README.md"
MONITOR_DBC = DBC_DIR / "canfdi_monitor.dbc"
DC_MOTOR_CONFIG = REPO / "deploy" / "config" / "dc_motor.yaml"


def _profile_dbcs() -> dict[str, str]:
    """DBC stem -> the (non-canfdi) bus profile that claims it."""
    from canfdi.firmware_sim.plants import PLANTS
    from canfdi.firmware_sim.profiles import PROFILES

    return {profile.dbc(plant): name for name, profile in PROFILES.items() if name != "canfdi"
            for plant in PLANTS if profile.dbc(plant) is not None}


PROFILE_DBCS = _profile_dbcs()
DBC_FILES = [p for p in ALL_DBC_FILES if p.stem not in PROFILE_DBCS and p != MONITOR_DBC]
"""The plant DBCs of canfdi's own bus (every file neither the monitor's nor a profile's)."""
PROFILE_DBC_FILES = [p for p in ALL_DBC_FILES if p.stem in PROFILE_DBCS]

HEADER = {"CRC": (0, 8, False, False, 0, 255, None), "Counter": (8, 8, False, False, 0, 255, None)}

# README sections whose ```dbc blocks the tests compare, line by line, with files.
MONITOR_SECTION = "Monitor messages"
WRITING_SECTION = "Writing a new DBC file"
DBC_BLOCK = re.compile(r"^```dbc\n(.*?)^```", flags=re.M | re.S)


def _stem(path: Path) -> str:
    return path.stem


def _choices(sig: Signal) -> dict[int, str] | None:
    return None if sig.choices is None else {int(k): str(v) for k, v in sig.choices.items()}


def _is_drive(msg: Message) -> bool:
    return msg.name.startswith("DRIVE_")


def _readme_section(title: str) -> str:
    """The text of the README's "## <title> ..." section, up to the next "## " heading."""
    parts = re.split(r"^## (.+)$", README.read_text(), flags=re.M)
    found = [text for heading, text in zip(parts[1::2], parts[2::2], strict=True)
             if heading.startswith(title)]
    assert len(found) == 1, f"dbc/README.md needs one section '## {title}'"
    return found[0]


def _dbc_lines(text: str) -> list[str]:
    """Every non-blank line of the ```dbc blocks of a README text, stripped."""
    blocks = DBC_BLOCK.findall(text)
    assert blocks, "no ```dbc blocks"
    return [line.strip() for block in blocks for line in block.splitlines() if line.strip()]


def _missing_lines(path: Path, lines: list[str]) -> list[str]:
    have = {line.strip() for line in path.read_text().splitlines()}
    return [line for line in lines if line not in have]


def test_every_readme_dbc_block_is_compared_with_files() -> None:
    """A ```dbc block outside the two sections the tests read would be checked by nothing."""
    total = len(DBC_BLOCK.findall(README.read_text()))
    compared = sum(len(DBC_BLOCK.findall(_readme_section(title)))
                   for title in (MONITOR_SECTION, WRITING_SECTION))
    assert compared == total


# --- plant DBCs of canfdi's own bus -------------------------------------------------------------


@pytest.fixture(scope="module", params=DBC_FILES, ids=_stem)
def dbc_file(request: pytest.FixtureRequest) -> Path:
    return request.param


@pytest.fixture(scope="module")
def db(dbc_file: Path) -> Database:
    return cantools.database.load_file(dbc_file, strict=True)


@pytest.fixture(scope="module")
def monitor_db() -> Database:
    return cantools.database.load_file(MONITOR_DBC, strict=True)


def test_every_plant_has_its_plant_dbc_and_every_plant_dbc_a_plant() -> None:
    from canfdi.firmware_sim.plants import PLANTS
    from canfdi.firmware_sim.profiles import PROFILES

    plants = {name: factory() for name, factory in PLANTS.items()}
    assert sorted(p.name for p in DBC_FILES) == sorted(p.dbc for p in plants.values()
                                                       if p.dbc is not None)
    for name, plant in plants.items():
        if plant.dbc is None:
            # A plant that does not speak canfdi's bus speaks another profile's.
            assert PROFILES["canfdi"].dbc(name) is None, name
            assert any(PROFILES[other].dbc(name) in PROFILE_DBCS for other in PROFILES), name
            continue
        assert PROFILES["canfdi"].dbc(name) == Path(plant.dbc).stem, name
    assert "motor_drive.dbc" in {p.name for p in DBC_FILES}


def test_cantools_dump_cli_accepts_the_file(dbc_file: Path) -> None:
    result = subprocess.run([sys.executable, "-m", "cantools", "dump", str(dbc_file)],
                            capture_output=True, text=True, timeout=120, check=False)
    assert result.returncode == 0, result.stderr
    names = re.findall(r"^BO_ \d+ (\w+):", dbc_file.read_text(), flags=re.M)
    assert names and all(name.startswith("DRIVE_") for name in names), names
    for name in names:
        assert name in result.stdout, name
    assert "FDI_" not in result.stdout, "the monitor's messages are in canfdi_monitor.dbc"


def test_nodes_senders_and_receivers(db: Database, dbc_file: Path) -> None:
    assert sorted(node.name for node in db.nodes) == ["DRIVE", "FDI"]
    assert all(node.comment for node in db.nodes)
    assert db.version == f"canfdi {dbc_file.stem} 1"
    assert db.messages
    for msg in db.messages:
        assert _is_drive(msg), msg.name
        assert msg.senders == ["DRIVE"], msg.name
        for sig in msg.signals:
            assert sig.receivers == ["FDI"], (msg.name, sig.name)


def test_file_comment_names_the_plant_only(dbc_file: Path) -> None:
    """One file-level CM_ (plant, seed, dt); the monitor's messages are not in this file."""
    comments = re.findall(r'^CM_ "(.*)";$', dbc_file.read_text(), flags=re.M)
    assert len(comments) == 1, comments
    assert "dt = " in comments[0] and comments[0].endswith("Conventions: dbc/README.md.")
    assert "monitor" not in comments[0]


def test_readme_plant_blocks_are_in_the_file_verbatim(dbc_file: Path) -> None:
    missing = _missing_lines(dbc_file, _dbc_lines(_readme_section(WRITING_SECTION)))
    assert not missing, f"{dbc_file.name} lacks these README lines: {missing[:5]}"


def _assert_e2e_header(msg: Message) -> None:
    by_name = {s.name: s for s in msg.signals}
    for name, start in (("CRC", 0), ("Counter", 8)):
        assert name in by_name, (msg.name, name)
        sig = by_name[name]
        assert (sig.start, sig.length, sig.byte_order, sig.is_signed, sig.is_float,
                sig.scale, sig.offset, sig.minimum, sig.maximum) == (
            start, 8, "little_endian", False, False, 1, 0, 0, 255), (msg.name, name)


def test_every_message_starts_with_the_e2e_header(db: Database) -> None:
    for msg in db.messages:
        _assert_e2e_header(msg)


def test_ids_dlc_and_signal_conventions(db: Database, monitor_db: Database) -> None:
    ids = [m.frame_id for m in db.messages]
    assert ids == sorted(set(ids)), "ascending, distinct IDs"
    assert min(ids) > max(m.frame_id for m in monitor_db.messages), (
        "drive IDs above the monitor's default IDs")
    for msg in db.messages:
        assert not msg.is_extended_frame and not msg.is_multiplexed(), msg.name
        assert msg.frame_id <= e2e.MAX_ARBITRATION_ID, msg.name
        assert msg.comment, msg.name
        assert {"GenMsgCycleTime", "GenMsgSendType"} <= set(msg.dbc.attributes), msg.name
        assert msg.send_type == "Cyclic" and msg.cycle_time, msg.name
        starts = []
        for sig in msg.signals:
            assert sig.byte_order == "little_endian", (msg.name, sig.name)
            assert sig.comment, (msg.name, sig.name)
            assert (sig.start + sig.length) <= 8 * msg.length, (msg.name, sig.name)
            if sig.name in HEADER:
                continue
            assert (sig.length, sig.is_signed, sig.is_float, sig.offset) == (16, True, False, 0), (
                msg.name, sig.name)
            # Declared range = full raw range.
            assert (sig.minimum, sig.maximum) == pytest.approx(
                (-32768 * sig.scale, 32767 * sig.scale), rel=1e-9), (msg.name, sig.name)
            starts.append(sig.start)
        assert starts and set(starts) <= {16, 32, 48}, (msg.name, starts)
        assert msg.length == 8 or (msg.length == 4 and starts == [16]), msg.name
    assert len({m.cycle_time for m in db.messages}) == 1, "drive messages share the period"


def test_no_id_is_confusable_under_the_crc(db: Database, monitor_db: Database) -> None:
    """A frame replayed under another ID of the same bus, the monitor's default IDs included,
    must fail the E2E check."""
    ids = [msg.frame_id for msg in db.messages]
    monitor_ids = [msg.frame_id for msg in monitor_db.messages]
    assert not set(ids) & set(monitor_ids)
    assert e2e.confusable_ids(ids + monitor_ids) == []


def _raw_limits(sig: Signal) -> tuple[int, int]:
    if sig.is_signed:
        return -(2 ** (sig.length - 1)), 2 ** (sig.length - 1) - 1
    return 0, 2**sig.length - 1


def _physical_limits(sig: Signal) -> tuple[float, float]:
    raw_lo, raw_hi = _raw_limits(sig)
    lo = sig.minimum if sig.minimum is not None else raw_lo * sig.scale + sig.offset
    hi = sig.maximum if sig.maximum is not None else raw_hi * sig.scale + sig.offset
    return lo, hi


def _value(sig: Signal, rng: np.random.Generator, where: str) -> float:
    """An in-range physical value on the signal's grid: the minimum, the maximum or random."""
    if sig.is_float:
        return float(np.float32({"min": -3.0e38, "max": 3.0e38}.get(where, rng.normal(0, 1e3))))
    lo, hi = _physical_limits(sig)
    raw_lo = int(np.ceil((lo - sig.offset) / sig.scale - 1e-9))
    raw_hi = int(np.floor((hi - sig.offset) / sig.scale + 1e-9))
    if where == "min":
        raw = raw_lo
    elif where == "max":
        raw = raw_hi
    else:
        raw = int(rng.integers(raw_lo, raw_hi + 1))
    # Clip: raw * scale can land one ulp outside a limit written in decimal.
    return float(np.clip(raw * sig.scale + sig.offset, lo, hi))


def _assert_decoded(msg: Message, decoded: dict, values: dict) -> None:
    for sig in msg.signals:
        if sig.name in HEADER:
            continue
        got, want = decoded[sig.name], values[sig.name]
        if sig.is_float:
            assert got == np.float32(want), (msg.name, sig.name)
        else:
            assert abs(got - want) <= sig.scale / 2, (msg.name, sig.name, got, want)


def test_encode_decode_round_trip_with_e2e(db: Database) -> None:
    rng = np.random.default_rng(20240601)
    for msg in db.messages:
        for trial in range(50):
            where = ("min", "max", "random")[min(trial, 2)]
            values = {s.name: _value(s, rng, where) for s in msg.signals}
            values["CRC"] = values["Counter"] = 0
            counter = int(rng.integers(0, 10**6))
            frame = e2e.protect(msg.frame_id, msg.encode(values), counter)
            assert len(frame) == msg.length
            assert e2e.check(msg.frame_id, frame), msg.name
            decoded = msg.decode(frame, decode_choices=False)
            assert decoded["CRC"] == frame[0] and decoded["Counter"] == counter % 256
            _assert_decoded(msg, decoded, values)


def _single_bit_errors(frame: bytes):
    """Every copy of the frame with one bit flipped."""
    for byte in range(len(frame)):
        for bit in range(8):
            corrupted = bytearray(frame)
            corrupted[byte] ^= 1 << bit
            yield bytes(corrupted)


def test_a_corrupted_encoded_frame_fails_the_check(db: Database) -> None:
    for msg in db.messages:
        frame = e2e.protect(msg.frame_id, msg.encode({s.name: 0 for s in msg.signals}), 7)
        assert e2e.check(msg.frame_id, frame), msg.name
        for corrupted in _single_bit_errors(frame):
            assert not e2e.check(msg.frame_id, corrupted), (msg.name, corrupted.hex())


# --- the plants' names and the scenarios' values ----------------------------------------------


def _plants() -> list:
    """The plants with a DBC of canfdi's own bus (the servo axis has none: float_node only)."""
    from canfdi.firmware_sim.plants import PLANTS

    return [plant for plant in (factory() for factory in PLANTS.values())
            if plant.dbc is not None]


def _drive_signals(database: Database) -> dict[str, Signal]:
    return {s.name: s for m in database.messages if _is_drive(m) for s in m.signals
            if s.name not in HEADER}


def _database_of(plant) -> Database:
    return cantools.database.load_file(DBC_DIR / plant.dbc, strict=True)


@pytest.mark.parametrize("plant", _plants(), ids=lambda p: p.name)
def test_drive_signals_are_the_plant_names(plant) -> None:
    database = _database_of(plant)
    signals = _drive_signals(database)
    names = (*plant.input_names, *plant.output_names, *plant.reference_names)
    assert sorted(signals) == sorted(names)
    # Quantisation step at most the sensor noise (README rule b).
    for name, sigma in zip(plant.output_names, plant.noise_defaults().measurement, strict=True):
        assert signals[name].scale <= sigma * (1 + 1e-9), name
    cycle_ms = round(plant.dt * 1000)
    assert {m.cycle_time for m in database.messages if _is_drive(m)} == {cycle_ms}


def _scenarios() -> list[Path]:
    return sorted((REPO / "canfdi" / "firmware_sim" / "scenarios").glob("*.yaml"))


def _scenarios_of(plant: str) -> list[Path]:
    import yaml

    return [p for p in _scenarios() if yaml.safe_load(p.read_text()).get("plant") == plant]


def _scenarios_on_own_bus_dbcs() -> list[Path]:
    """The scenarios of the plants that have a DBC of canfdi's own bus."""
    own = {plant.name for plant in _plants()}
    return [p for name in own for p in _scenarios_of(name)]


@pytest.mark.parametrize("scenario_path", sorted(_scenarios_on_own_bus_dbcs()), ids=_stem)
def test_scenario_values_stay_inside_the_signal_ranges(scenario_path: Path) -> None:
    from canfdi.firmware_sim.scenario import load_scenario
    from canfdi.firmware_sim.simulate import simulate

    scenario = load_scenario(scenario_path)
    plant = scenario.make_plant()
    signals = _drive_signals(_database_of(plant))
    for i in range(len(scenario.drives)):
        run = simulate(scenario.drive_scenario(i))
        series = {
            **{name: run.u_c[:, j] for j, name in enumerate(plant.input_names)},
            **{name: run.z[:, j] for j, name in enumerate(plant.output_names)},
            **{name: run.ref[:, j] for j, name in enumerate(plant.reference_names)},
        }
        for name, values in series.items():
            lo, hi = _physical_limits(signals[name])
            assert np.all(np.isfinite(values)), name
            assert lo <= values.min() and values.max() <= hi, (
                f"{scenario_path.name}: {name} spans {values.min():.4g} .. "
                f"{values.max():.4g}, outside the DBC range {lo} .. {hi}")


# --- the monitor's DBC (canfdi_monitor.dbc) ------------------------------------------------------

# name: (default frame_id, dlc, cycle_time (None: event-driven), {signal: (start, length, signed,
# float, minimum, maximum, choices)}) -- the monitor's messages as dbc/README.md documents them.
KIND = {0: "none", 1: "actuator", 2: "sensor"}
FLOAT = (32, 32, True, True, -3.4e38, 3.4e38, None)
MONITOR = {
    "FDI_FAULT": (0x080, 8, None, {
        **HEADER,
        "Kind": (16, 2, False, False, 0, 2, KIND),
        "State": (18, 2, False, False, 0, 3,
                  {0: "cleared", 1: "detected", 2: "named", 3: "accepted"}),
        "Drive": (20, 3, False, False, 0, 7, None),
        "Index": (24, 8, False, False, 0, 255, None),
        "Sample": (32, 32, False, False, 0, 2**32 - 1, None),
    }),
    "FDI_ESTIMATE": (0x081, 8, None, {
        **HEADER,
        "Kind": (16, 2, False, False, 0, 2, KIND),
        "Param": (18, 3, False, False, 0, 5, {0: "eta", 1: "lambda", 2: "bias", 3: "eta_std",
                                             4: "lambda_std", 5: "bias_std"}),
        "Drive": (21, 3, False, False, 0, 7, None),
        "Index": (24, 8, False, False, 0, 255, None),
        "Value": FLOAT,
    }),
    "FDI_STATUS": (0x082, 8, 1000, {
        **HEADER,
        "State": (16, 4, False, False, 0, 15, {0: "starting", 1: "monitoring", 2: "diagnosing",
                                              3: "degraded", 4: "bus_error", 5: "teaching",
                                              6: "mismatch", 7: "no_traffic", 8: "checking",
                                              9: "quiet", 10: "named"}),
        "Drive": (20, 3, False, False, 0, 7, None),
        "ActiveFaults": (23, 4, False, False, 0, 15, None),
        "Samples": (27, 21, False, False, 0, 2**21 - 1, None),
        "InvalidFrames": (48, 16, False, False, 0, 2**16 - 1, None),
    }),
    "FDI_RESIDUAL": (0x083, 8, None, {
        **HEADER,
        "Index": (16, 8, False, False, 0, 255, None),
        "Alarm": (24, 2, False, False, 0, 2, {0: "none", 1: "up", 2: "down"}),
        "Drive": (26, 3, False, False, 0, 7, None),
        "Value": FLOAT,
    }),
}


def test_cantools_dump_cli_accepts_the_monitor_dbc() -> None:
    result = subprocess.run([sys.executable, "-m", "cantools", "dump", str(MONITOR_DBC)],
                            capture_output=True, text=True, timeout=120, check=False)
    assert result.returncode == 0, result.stderr
    for name in MONITOR:
        assert name in result.stdout, name
    assert "DRIVE_" not in result.stdout


def test_monitor_dbc_has_the_monitor_node_and_its_four_messages(monitor_db: Database) -> None:
    assert [node.name for node in monitor_db.nodes] == ["FDI"]
    assert monitor_db.nodes[0].comment
    assert monitor_db.version == "canfdi monitor 6"
    # In the order bus.monitor.base numbers them: base, base + 1, ... (the defaults from 0x080).
    assert [m.name for m in monitor_db.messages] == list(MONITOR) == list(MONITOR_MESSAGES)
    assert [m.frame_id for m in monitor_db.messages] == [0x080, 0x081, 0x082, 0x083]
    for msg in monitor_db.messages:
        assert msg.senders == ["FDI"], msg.name
        assert msg.comment, msg.name
        assert all(sig.comment for sig in msg.signals), msg.name
        assert {"GenMsgCycleTime", "GenMsgSendType"} <= set(msg.dbc.attributes), msg.name


def test_monitor_messages_follow_the_readme(monitor_db: Database) -> None:
    for name, (frame_id, dlc, cycle_time, signals) in MONITOR.items():
        msg = monitor_db.get_message_by_name(name)
        assert (msg.frame_id, msg.length, msg.is_extended_frame) == (frame_id, dlc, False), name
        assert not msg.is_multiplexed(), name
        assert msg.cycle_time == cycle_time, name
        assert msg.send_type == ("Cyclic" if cycle_time else "Event"), name
        got = {s.name: (s.start, s.length, s.is_signed, s.is_float, s.minimum, s.maximum,
                        _choices(s)) for s in msg.signals}
        assert got == signals, name
        for sig in msg.signals:
            assert (sig.byte_order, sig.scale, sig.offset) == ("little_endian", 1, 0), sig.name
            assert sig.receivers == [], (name, sig.name)  # Vector__XXX: any logger or HMI
        _assert_e2e_header(msg)


def test_the_drive_signal_names_every_drive_a_config_may_have(monitor_db: Database) -> None:
    for msg in monitor_db.messages:
        drive = msg.get_signal_by_name("Drive")
        assert drive.maximum == 2**drive.length - 1 >= MAX_DRIVES - 1, msg.name


TABLE_HEADING = re.compile(
    r"^### `(\w+)` \(default ID 0x([0-9A-F]+), DLC (\d+), (?:event|cyclic (\d+) ms)\)$",
    flags=re.M)
TABLE_ROW = re.compile(r"^\| `(\w+)` \| (\d+)\\\|(\d+) \| (unsigned|signed|float32) \| ([^|]*) \|",
                       flags=re.M)


def _readme_values(text: str) -> tuple[float, float] | dict[int, str]:
    """A table's "values" cell: "lo .. hi", or a VAL_ table "0 none, 1 actuator, ..."."""
    match = re.fullmatch(r"(-?[0-9.E+]+) \.\. (-?[0-9.E+]+)", text)
    if match:
        return float(match[1]), float(match[2])
    pairs = re.findall(r"(\d+) (\w+)", text)
    assert pairs and ", ".join(f"{k} {v}" for k, v in pairs) == text, text
    return {int(k): v for k, v in pairs}


def _readme_monitor_tables() -> dict[str, tuple[int, int, int | None, list[tuple]]]:
    """message -> (default ID, DLC, cycle time, [(signal, start, length, type, values)]), as
    the "Monitor messages" section of dbc/README.md tabulates them."""
    text = _readme_section(MONITOR_SECTION)
    headings = list(TABLE_HEADING.finditer(text))
    tables = {}
    for i, heading in enumerate(headings):
        end = headings[i + 1].start() if i + 1 < len(headings) else len(text)
        body = text[heading.end():end].split("\n### ")[0]
        rows = [(name, int(start), int(length), kind, _readme_values(values.strip()))
                for name, start, length, kind, values in TABLE_ROW.findall(body)]
        cycle = int(heading[4]) if heading[4] else None
        tables[heading[1]] = (int(heading[2], 16), int(heading[3]), cycle, rows)
    return tables


def test_readme_tables_describe_the_monitor_dbc(monitor_db: Database) -> None:
    tables = _readme_monitor_tables()
    assert list(tables) == list(MONITOR_MESSAGES)
    for name, (frame_id, dlc, cycle_time, rows) in tables.items():
        msg = monitor_db.get_message_by_name(name)
        assert (msg.frame_id, msg.length, msg.cycle_time) == (frame_id, dlc, cycle_time), name
        want = [(sig.name, sig.start, sig.length,
                 "float32" if sig.is_float else "signed" if sig.is_signed else "unsigned",
                 _choices(sig) or (sig.minimum, sig.maximum)) for sig in msg.signals]
        assert rows == want, name


def test_readme_monitor_blocks_are_in_the_monitor_dbc_verbatim() -> None:
    lines = _dbc_lines(_readme_section(MONITOR_SECTION))
    assert any(line.startswith("BO_ ") for line in lines)
    missing = _missing_lines(MONITOR_DBC, lines)
    assert not missing, f"canfdi_monitor.dbc lacks these README lines: {missing[:5]}"


def _monitor_frames(**monitor) -> MonitorFrames:
    """The monitor's frames as the DC motor's config, with this bus.monitor, builds them."""
    config = load_config(DC_MOTOR_CONFIG)
    bus = dataclasses.replace(config.bus, monitor=MonitorFramesConfig(**monitor))
    return MonitorFrames.from_config(dataclasses.replace(config, bus=bus), [])


def test_monitor_frames_round_trip_through_the_monitor_dbc(monitor_db: Database) -> None:
    """What the monitor sends (canfdi.bus.monitorframes) decodes with canfdi_monitor.dbc, and
    passes the E2E check at the message's default ID."""
    frames = _monitor_frames()
    rng = np.random.default_rng(20250615)
    for msg in monitor_db.messages:
        assert frames.keys[msg.name] == (msg.frame_id, False)
        for trial in range(50):
            where = ("min", "max", "random")[min(trial, 2)]
            values = {s.name: _value(s, rng, where) for s in msg.signals if s.name not in HEADER}
            key, frame = frames.encode(msg.name, values)
            assert key == (msg.frame_id, False) and len(frame) == msg.length
            assert e2e.check(msg.frame_id, frame), msg.name
            decoded = msg.decode(frame, decode_choices=False)
            assert decoded["CRC"] == frame[0] and decoded["Counter"] == trial, msg.name
            _assert_decoded(msg, decoded, values)


def test_monitor_frames_at_ids_the_config_chooses(monitor_db: Database) -> None:
    """bus.monitor moves the frames: same signals, the CRC over the new ID; e2e none sends the
    header as zeros."""
    default = _monitor_frames()
    moved = _monitor_frames(base=0x6E0)
    bare = _monitor_frames(e2e="none")
    for i, msg in enumerate(monitor_db.messages):
        values = {"Drive": 5}
        (fid, _), at_default = default.encode(msg.name, values)
        (moved_id, _), at_base = moved.encode(msg.name, values)
        _, unprotected = bare.encode(msg.name, values)
        assert (fid, moved_id) == (msg.frame_id, 0x6E0 + i)
        assert msg.decode(at_base, decode_choices=False)["Drive"] == 5
        assert at_base[1:] == at_default[1:] and at_base[0] != at_default[0], msg.name
        assert e2e.check(moved_id, at_base) and not e2e.check(fid, at_base), msg.name
        assert unprotected == bytes(2) + at_default[2:], msg.name
    one = _monitor_frames(ids={"FDI_STATUS": 0x6F0})
    assert one.keys["FDI_STATUS"] == (0x6F0, False) and one.keys["FDI_FAULT"] == (0x080, False)


def test_a_corrupted_monitor_frame_fails_the_check(monitor_db: Database) -> None:
    frames = _monitor_frames()
    other_ids = {m.name: [o.frame_id for o in monitor_db.messages if o is not m]
                 for m in monitor_db.messages}
    for msg in monitor_db.messages:
        _, frame = frames.encode(msg.name, {"Drive": 3})
        assert e2e.check(msg.frame_id, frame), msg.name
        for corrupted in _single_bit_errors(frame):
            assert not e2e.check(msg.frame_id, corrupted), (msg.name, corrupted.hex())
        for other in other_ids[msg.name]:
            assert not e2e.check(other, frame), (msg.name, hex(other))


def test_a_plant_dbc_and_the_monitor_dbc_load_as_one_bus(dbc_file: Path) -> None:
    """The README's way of seeing a whole canfdi bus in one cantools Database."""
    database = cantools.database.load_file(dbc_file, strict=True)
    database.add_dbc_file(MONITOR_DBC)
    names = [m.name for m in database.messages]
    assert sorted(names) == sorted(
        [*re.findall(r"^BO_ \d+ (\w+):", dbc_file.read_text(), flags=re.M), *MONITOR])
    assert len({m.frame_id for m in database.messages}) == len(names)


# --- the other bus profiles' DBCs (vendor style: no E2E header, no monitor block) -------------


def test_every_profile_dbc_has_landed() -> None:
    assert sorted(PROFILE_DBCS) == sorted(p.stem for p in PROFILE_DBC_FILES)
    assert {"dc_motor_cia402", "dc_motor_float"} <= set(PROFILE_DBCS)


@pytest.fixture(scope="module", params=PROFILE_DBC_FILES, ids=_stem)
def profile_db(request: pytest.FixtureRequest) -> Database:
    return cantools.database.load_file(request.param, strict=True)


@pytest.mark.parametrize("path", PROFILE_DBC_FILES, ids=_stem)
def test_cantools_dump_cli_accepts_a_profile_dbc(path: Path) -> None:
    result = subprocess.run([sys.executable, "-m", "cantools", "dump", str(path)],
                            capture_output=True, text=True, timeout=120, check=False)
    assert result.returncode == 0, result.stderr


def test_profile_dbc_conventions(profile_db: Database) -> None:
    assert sorted(node.name for node in profile_db.nodes) == ["DRIVE", "MASTER"]
    assert all(node.comment for node in profile_db.nodes)
    ids = [m.frame_id for m in profile_db.messages]
    assert ids == sorted(ids) and len(set(ids)) == len(ids), "ascending, distinct IDs"
    for msg in profile_db.messages:
        assert not msg.is_extended_frame and not msg.is_multiplexed(), msg.name
        assert msg.frame_id <= 0x7FF and 0 <= msg.length <= 8, msg.name
        assert msg.senders in (["DRIVE"], ["MASTER"]), msg.name
        assert msg.comment and msg.cycle_time and msg.send_type == "Cyclic", msg.name
        assert not msg.name.startswith("FDI_"), "the monitor's frames are in its own DBC"
        for sig in msg.signals:
            assert sig.byte_order == "little_endian", (msg.name, sig.name)
            assert sig.comment, (msg.name, sig.name)
            assert sig.start + sig.length <= 8 * msg.length, (msg.name, sig.name)
            assert sig.receivers and set(sig.receivers) <= {"DRIVE", "MASTER"}, sig.name
            assert not sig.is_float or (sig.length, sig.minimum, sig.maximum) == (
                32, -3.4e38, 3.4e38), sig.name


def test_profile_dbc_encode_decode_round_trip(profile_db: Database) -> None:
    rng = np.random.default_rng(20250601)
    for msg in profile_db.messages:
        for trial in range(50):
            where = ("min", "max", "random")[min(trial, 2)]
            values = {s.name: _value(s, rng, where) for s in msg.signals}
            frame = msg.encode(values)
            assert len(frame) == msg.length
            decoded = msg.decode(frame, decode_choices=False)
            for sig in msg.signals:
                got, want = decoded[sig.name], values[sig.name]
                if sig.is_float:
                    assert got == np.float32(want), (msg.name, sig.name)
                else:
                    assert abs(got - want) <= sig.scale / 2, (msg.name, sig.name, got, want)


def _configs_of_profile_dbcs() -> list[Path]:
    import yaml

    out = []
    for path in sorted((REPO / "deploy" / "config").glob("*.yaml")):
        bus = yaml.safe_load(path.read_text()).get("bus") or {}
        if str(bus.get("dbc", "")).removesuffix(".dbc") in PROFILE_DBCS:
            out.append(path)
    return out


def _mapped_signals(config: Path) -> tuple[dict, dict[str, Signal]]:
    """(document, model name -> the DBC signal its bus.map names) of a monitor config."""
    doc, mapped = _mapped(config)
    return doc, {name: sig for name, (_, sig) in mapped.items()}


def _mapped(config: Path) -> tuple[dict, dict[str, tuple[Message, Signal]]]:
    """(document, model name -> the DBC message and signal its bus.map names)."""
    import yaml

    doc = yaml.safe_load(config.read_text())
    database = cantools.database.load_file(DBC_DIR / f"{doc['bus']['dbc']}.dbc", strict=True)
    signals = {}
    for name, where in doc["bus"]["map"].items():
        if isinstance(where, str):
            message_name, signal_name = where.split(".")
            message = database.get_message_by_name(message_name)
        else:
            ref = where["message"]
            message = (database.get_message_by_name(ref) if isinstance(ref, str)
                       else database.get_message_by_frame_id(ref))
            signal_name = where["signal"]
        signals[name] = (message, message.get_signal_by_name(signal_name))
    return doc, signals


def test_monitor_configs_of_profile_dbcs_map_every_model_signal() -> None:
    configs = _configs_of_profile_dbcs()
    assert {p.stem for p in configs} >= {"dc_motor_cia402", "dc_motor_float",
                                          "dc_motor_two_drives_cia402"}
    for config in configs:
        doc, signals = _mapped_signals(config)
        names = [*doc["signals"]["inputs"], *doc["signals"]["outputs"]]
        assert sorted(signals) == sorted(names), config.name


def _plant_of_config(config: Path) -> str:
    """The emulated plant whose input and output names a config's signals are."""
    import yaml

    from canfdi.firmware_sim.plants import PLANTS

    signals = yaml.safe_load(config.read_text())["signals"]
    for name, factory in PLANTS.items():
        plant = factory()
        if (list(plant.input_names), list(plant.output_names)) == (signals["inputs"],
                                                                   signals["outputs"]):
            return name
    raise AssertionError(f"no emulated plant has the signals of {config.name}")


def _configs_and_scenarios() -> list[tuple[Path, Path]]:
    """Every profile config with every shipped scenario of its plant."""
    return [(config, scenario) for config in _configs_of_profile_dbcs()
            for scenario in _scenarios_of(_plant_of_config(config))]


@pytest.mark.parametrize(("config", "scenario_path"), _configs_and_scenarios(),
                         ids=lambda p: p.stem)
def test_scenario_values_stay_inside_the_mapped_signal_ranges(config: Path,
                                                              scenario_path: Path) -> None:
    """Every shipped scenario's values (faults and noise included), in the signals a profile's
    monitor config for its plant maps them to, stay inside each signal's range."""
    from canfdi.firmware_sim.scenario import load_scenario
    from canfdi.firmware_sim.simulate import simulate

    _, signals = _mapped_signals(config)
    scenario = load_scenario(scenario_path)
    plant = scenario.make_plant()
    for i in range(len(scenario.drives)):
        run = simulate(scenario.drive_scenario(i))
        series = {
            **{name: run.u_c[:, j] for j, name in enumerate(plant.input_names)},
            **{name: run.z[:, j] for j, name in enumerate(plant.output_names)},
        }
        for name, values in series.items():
            lo, hi = _physical_limits(signals[name])
            assert np.all(np.isfinite(values)), name
            assert lo <= values.min() and values.max() <= hi, (
                f"{scenario_path.name}: {name} spans {values.min():.4g} .. "
                f"{values.max():.4g}, outside {signals[name].name}'s range {lo} .. {hi}")


# --- canfdi.dbc and packaging -------------------------------------------------------------------


def test_package_lists_the_files() -> None:
    assert dbc_package.available() == [p.stem for p in ALL_DBC_FILES]
    assert {"canfdi_monitor", "motor_drive"} <= set(dbc_package.available())
    assert dbc_package.path("motor_drive") == dbc_package.path("motor_drive.dbc")
    shipped = dbc_package.path("motor_drive")
    assert shipped.read_bytes() == (DBC_DIR / "motor_drive.dbc").read_bytes()
    assert isinstance(dbc_package.load("motor_drive"), Database)
    assert dbc_package.path("canfdi_monitor") == MONITOR_DBC
    monitor = dbc_package.load("canfdi_monitor")
    assert [m.name for m in monitor.messages] == list(MONITOR_MESSAGES)


def test_the_monitor_config_s_default_dbc_is_the_shipped_monitor_dbc() -> None:
    default = MonitorFramesConfig().dbc
    assert default == MONITOR_DBC.stem and default in dbc_package.available()
    assert load_config(DC_MOTOR_CONFIG).bus.monitor.dbc == default


FILE_ROW = re.compile(r"^\| `(\w+)\.dbc` \| ([^|]+) \| [^|]* \| ([^|]+) \|$", flags=re.M)


def test_readme_file_table_lists_every_file_its_kind_and_messages() -> None:
    rows = {match[1]: (match[2].strip(), re.findall(r"`(\w+)` 0x([0-9A-F]+)", match[3]))
            for match in FILE_ROW.finditer(README.read_text())}
    assert sorted(rows) == [p.stem for p in ALL_DBC_FILES]
    plants = {p.stem for p in DBC_FILES}
    for path in ALL_DBC_FILES:
        kind, messages = rows[path.stem]
        want_kind = ("plant" if path.stem in plants else "monitor" if path == MONITOR_DBC
                     else f"profile `{PROFILE_DBCS[path.stem]}`")
        assert kind == want_kind, path.name
        database = cantools.database.load_file(path, strict=True)
        assert [(name, int(fid, 16)) for name, fid in messages] == [
            (m.name, m.frame_id) for m in database.messages], path.name


def test_package_names_what_is_available() -> None:
    with pytest.raises(FileNotFoundError, match="motor_drive"):
        dbc_package.path("no_such_bus")
    for bad in ("", "../pyproject.toml", "dbc/motor_drive"):
        with pytest.raises(ValueError, match="name"):
            dbc_package.path(bad)


def test_pyproject_ships_dbc_and_lists_every_package() -> None:
    from setuptools import find_namespace_packages

    config = tomllib.loads((REPO / "pyproject.toml").read_text())["tool"]["setuptools"]
    assert config["package-dir"]["canfdi.dbc"] == "dbc"
    assert {"*.dbc", "*.md"} <= set(config["package-data"]["canfdi.dbc"])
    listed = set(config["packages"])
    found = {
        p for p in find_namespace_packages(where=str(REPO), include=["canfdi*"])
        if "__pycache__" not in p.split(".")
    }
    # The list is explicit (find cannot rename dbc/ to canfdi.dbc), so a new subpackage must be
    # added by hand or it silently drops out of the wheel.
    assert found | {"canfdi.dbc"} <= listed, sorted(found - listed)


# The shipped scenario each profile config is written for.
CONFIG_SCENARIOS = {"dc_motor_cia402": "dc_motor_consecutive_cia402",
                    "dc_motor_float": "dc_motor_consecutive_float",
                    "dc_motor_two_drives_cia402": "dc_motor_two_drives_cia402",
                    "servo_axis_odrive": "servo_axis_sensor_faults"}
# CANopen's predefined connection set: NMT, SYNC + EMCY, TIME, PDOs, SDOs, heartbeat, LSS.
CANOPEN_IDS = {0x000, *range(0x080, 0x100), 0x100, *range(0x181, 0x580), *range(0x581, 0x680),
               *range(0x701, 0x780), 0x7E4, 0x7E5}


def _frame_id(template: str | None, message: Message, node: int | None,
              shared: list = ()) -> int:
    """The message's ID on drive ``node`` (a message of bus.node.shared keeps its DBC ID)."""
    if template is None or node is None or message.name in shared or message.frame_id in shared:
        return message.frame_id
    return int(eval(template, {"__builtins__": {}}, {"id": message.frame_id, "node": node}))


@pytest.mark.parametrize("config", _configs_of_profile_dbcs(), ids=_stem)
def test_monitor_config_reads_the_emulated_bus(config: Path) -> None:
    """The config, as docs/bus.md reads it, finds on the emulator's bus: every drive's IDs (the
    DBC's after bus.node.id), the clock's message, each model signal in the mapped message
    carrying that drive's values; its own frames at IDs no drive uses (nor, on CANopen, a
    predefined function code)."""
    from canfdi.firmware_sim.emitter import frame_log
    from canfdi.firmware_sim.scenario import load_scenario

    doc, mapped = _mapped(config)
    bus = doc["bus"]
    database = cantools.database.load_file(DBC_DIR / f"{bus['dbc']}.dbc", strict=True)
    template = (bus.get("node") or {}).get("id")
    shared = (bus.get("node") or {}).get("shared", [])
    drives = doc.get("drives") or [{"name": doc["name"], "node": None}]
    log = frame_log(load_scenario(CONFIG_SCENARIOS[config.stem]), duration=2.0)
    if drives[0]["node"] is not None:
        assert [d["node"] for d in drives] == [d.node for d in log.drives]
    on_bus = set(log.frames.id.tolist())
    expected = {_frame_id(template, m, d["node"], shared) for m in database.messages
                for d in drives}
    assert expected == on_bus
    clock = bus["clock"]
    if clock["kind"] == "trigger":
        database.get_message_by_name(clock["message"])
    model = doc["signals"]
    remote = (log.frames.flags & 2) != 0
    for drive, run in zip(drives, log.drives, strict=True):
        for name, (message, sig) in mapped.items():
            fid = _frame_id(template, message, drive["node"], shared)
            rows = np.flatnonzero((log.frames.id == fid) & ~remote)
            payloads = log.frames.payloads()
            values = np.array([message.decode(payloads[r], decode_choices=False)[sig.name]
                               for r in rows])
            if name in model["inputs"]:
                want = run.chunk.u_c[:, model["inputs"].index(name)]
            else:
                want = run.chunk.z[:, model["outputs"].index(name)]
            np.testing.assert_allclose(values, want, rtol=1e-6, atol=sig.scale / 2 + 1e-9,
                                       err_msg=f"{config.name}: {drive['name']}.{name}")
    base = bus["monitor"]["base"]
    monitor_ids = set(range(base, base + 4))
    assert not monitor_ids & on_bus
    if bus.get("canopen"):
        assert not monitor_ids & CANOPEN_IDS
