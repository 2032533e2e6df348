"""Every DBC file in dbc/ against the conventions of dbc/README.md.

The files are globbed, so a new plant's DBC is checked as soon as it lands: against canfdi's
conventions (E2E header, monitor block, ...) unless a bus profile of the emulator other than
canfdi claims it (firmware_sim/profiles: cia402, float_node), whose vendor-style DBCs are
checked for what every DBC here must give (a strict load, comments, cycle times, round trips)
and, with the monitor configs that read them, for their signals' ranges.
"""

from __future__ import annotations

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

REPO = Path(__file__).resolve().parents[2]
DBC_DIR = REPO / "dbc"
ALL_DBC_FILES = sorted(DBC_DIR.glob("*.dbc"))
README = DBC_DIR / "README.md"


def _profile_dbcs() -> dict[str, str]:
    """DBC stem -> the (non-canfdi) bus profile that claims it."""
    from firmware_sim.plants import PLANTS
    from firmware_sim.profiles import PROFILES

    return {profile.dbc(plant): name for name, profile in PROFILES.items() if name != "canfdi"
            for plant in PLANTS if profile.dbc(plant) is not None}


PROFILE_DBCS = _profile_dbcs()
DBC_FILES = [p for p in ALL_DBC_FILES if p.stem not in PROFILE_DBCS]
"""The files of canfdi's own bus (every file no other profile claims)."""
PROFILE_DBC_FILES = [p for p in ALL_DBC_FILES if p.stem in PROFILE_DBCS]

# name: (frame_id, dlc, cycle_time (None: event-driven), {signal: (start, length, signed, float,
# minimum, maximum, choices)}) -- the monitor block of dbc/README.md.
KIND = {0: "none", 1: "actuator", 2: "sensor"}
HEADER = {"CRC": (0, 8, False, False, 0, 255, None), "Counter": (8, 8, False, False, 0, 255, None)}
FLOAT = (32, 32, True, True, -3.4e38, 3.4e38, None)
MONITOR = {
    "FDI_FAULT": (0x080, 8, None, {
        **HEADER,
        "Kind": (16, 2, False, False, 0, 2, KIND),
        "State": (18, 2, False, False, 0, 3,
                  {0: "cleared", 1: "detected", 2: "isolated", 3: "accepted"}),
        "Index": (24, 8, False, False, 0, 255, None),
        "Sample": (32, 32, False, False, 0, 2**32 - 1, None),
    }),
    "FDI_ESTIMATE": (0x081, 8, None, {
        **HEADER,
        "Kind": (16, 2, False, False, 0, 2, KIND),
        "Param": (18, 4, False, False, 0, 5, {0: "eta", 1: "lambda", 2: "bias", 3: "eta_std",
                                             4: "lambda_std", 5: "bias_std"}),
        "Index": (24, 8, False, False, 0, 255, None),
        "Value": FLOAT,
    }),
    "FDI_STATUS": (0x082, 8, 1000, {
        **HEADER,
        "State": (16, 4, False, False, 0, 4, {0: "starting", 1: "monitoring", 2: "diagnosing",
                                             3: "degraded", 4: "bus_error"}),
        "ActiveFaults": (20, 4, False, False, 0, 15, None),
        "Samples": (24, 24, False, False, 0, 2**24 - 1, None),
        "InvalidFrames": (48, 16, False, False, 0, 2**16 - 1, None),
    }),
    "FDI_RESIDUAL": (0x083, 8, None, {
        **HEADER,
        "Index": (16, 8, False, False, 0, 255, None),
        "Alarm": (24, 2, False, False, 0, 2, {0: "none", 1: "up", 2: "down"}),
        "Value": FLOAT,
    }),
}

def _stem(path: Path) -> str:
    return path.stem


@pytest.fixture(scope="module", params=DBC_FILES, ids=_stem)
def dbc_file(request: pytest.FixtureRequest) -> Path:
    return request.param


@pytest.fixture(scope="module")
def db(dbc_file: Path) -> Database:
    return cantools.database.load_file(dbc_file, strict=True)


def _choices(sig: Signal) -> dict[int, str] | None:
    return None if sig.choices is None else {int(k): str(v) for k, v in sig.choices.items()}


def _signal_layout(sig: Signal) -> tuple:
    return (sig.name, sig.start, sig.length, sig.byte_order, sig.is_signed, sig.is_float,
            sig.scale, sig.offset, sig.minimum, sig.maximum, sig.unit, _choices(sig), sig.comment)


def _message_layout(msg: Message) -> tuple:
    return (msg.name, msg.frame_id, msg.is_extended_frame, msg.length, msg.senders,
            msg.cycle_time, msg.send_type, msg.comment,
            tuple(_signal_layout(s) for s in msg.signals))


def _is_drive(msg: Message) -> bool:
    return msg.name.startswith("DRIVE_")


def test_there_is_a_dbc_file() -> None:
    assert [p.name for p in DBC_FILES if p.name == "motor_drive.dbc"] == ["motor_drive.dbc"]


def test_cantools_dump_cli_accepts_the_file(dbc_file: Path) -> None:
    result = subprocess.run([sys.executable, "-m", "cantools", "dump", str(dbc_file)],
                            capture_output=True, text=True, timeout=120, check=False)
    assert result.returncode == 0, result.stderr
    assert "FDI_FAULT" in result.stdout


def test_nodes_and_message_names(db: Database) -> None:
    assert sorted(node.name for node in db.nodes) == ["DRIVE", "FDI"]
    assert all(node.comment for node in db.nodes)
    for msg in db.messages:
        assert msg.name.startswith(("DRIVE_", "FDI_")), msg.name


def test_monitor_messages_follow_the_readme(db: Database) -> None:
    for name, (frame_id, dlc, cycle_time, signals) in MONITOR.items():
        msg = db.get_message_by_name(name)
        assert (msg.frame_id, msg.length, msg.is_extended_frame) == (frame_id, dlc, False), name
        assert msg.cycle_time == cycle_time, name
        assert msg.send_type == ("Cyclic" if cycle_time else "Event"), name
        got = {s.name: (s.start, s.length, s.is_signed, s.is_float, s.minimum, s.maximum,
                        _choices(s)) for s in msg.signals}
        assert got == signals, name
        for sig in msg.signals:
            assert (sig.byte_order, sig.scale, sig.offset) == ("little_endian", 1, 0), sig.name
    assert sorted(m.name for m in db.messages if not _is_drive(m)) == sorted(MONITOR)


def test_monitor_messages_are_identical_in_every_file() -> None:
    layouts = {}
    for path in DBC_FILES:
        database = cantools.database.load_file(path, strict=True)
        layouts[path.name] = [_message_layout(database.get_message_by_name(n)) for n in MONITOR]
    reference = layouts["motor_drive.dbc"]
    for name, layout in layouts.items():
        assert layout == reference, name


def _readme_dbc_lines() -> list[str]:
    blocks = re.findall(r"^```dbc\n(.*?)^```", README.read_text(), flags=re.M | re.S)
    assert blocks, "dbc/README.md has no ```dbc blocks"
    return [line.strip() for block in blocks for line in block.splitlines() if line.strip()]


def test_readme_monitor_block_is_in_the_file_verbatim(dbc_file: Path) -> None:
    lines = {line.strip() for line in dbc_file.read_text().splitlines()}
    missing = [line for line in _readme_dbc_lines() if line not in lines]
    assert not missing, f"{dbc_file.name} lacks these README lines: {missing[:5]}"


def test_every_message_starts_with_the_e2e_header(db: Database) -> None:
    for msg in db.messages:
        by_name = {s.name: s for s in msg.signals}
        for name, start in (("CRC", 0), ("Counter", 8)):
            sig = by_name[name]
            assert (sig.start, sig.length, sig.byte_order, sig.is_signed, sig.is_float,
                    sig.scale, sig.offset) == (start, 8, "little_endian", False, False, 1, 0), (
                msg.name, name)


def test_ids_dlc_and_signal_conventions(db: Database) -> None:
    drive = [m for m in db.messages if _is_drive(m)]
    assert drive
    assert max(MONITOR[n][0] for n in MONITOR) < min(m.frame_id for m in drive)
    for msg in db.messages:
        assert not msg.is_extended_frame and not msg.is_multiplexed(), msg.name
        assert msg.frame_id <= e2e.MAX_ARBITRATION_ID and 2 <= msg.length <= 8, msg.name
        assert msg.comment, msg.name
        assert "GenMsgCycleTime" in msg.dbc.attributes, msg.name
        for sig in msg.signals:
            assert sig.byte_order == "little_endian", (msg.name, sig.name)
            assert sig.comment, (msg.name, sig.name)
            assert (sig.start + sig.length) <= 8 * msg.length, (msg.name, sig.name)
    for msg in drive:
        assert msg.length in (4, 8), msg.name
        assert msg.send_type == "Cyclic" and msg.cycle_time, msg.name
        for sig in msg.signals:
            if sig.name in HEADER:
                continue
            assert (sig.length, sig.is_signed, sig.is_float, sig.offset) == (16, True, False, 0), (
                msg.name, sig.name)
            assert sig.start in (16, 32, 48), (msg.name, sig.name)
            assert sig.receivers == ["FDI"], (msg.name, sig.name)
    assert len({m.cycle_time for m in drive}) == 1, "drive messages share the control period"


def test_senders(db: Database) -> None:
    for msg in db.messages:
        assert msg.senders == (["DRIVE"] if _is_drive(msg) else ["FDI"]), msg.name


def test_no_two_ids_of_a_file_are_confusable_under_the_crc(db: Database) -> None:
    """A frame replayed under another ID of the same bus must fail the E2E check."""
    assert e2e.confusable_ids([msg.frame_id for msg in db.messages]) == []


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
            for sig in msg.signals:
                if sig.name in HEADER:
                    continue
                got, want = decoded[sig.name], values[sig.name]
                if sig.is_float:
                    assert got == np.float32(want), (msg.name, sig.name)
                else:
                    assert abs(got - want) <= sig.scale / 2, (msg.name, sig.name, got, want)


def test_a_corrupted_encoded_frame_fails_the_check(db: Database) -> None:
    msg = next(m for m in db.messages if _is_drive(m))
    frame = bytearray(e2e.protect(msg.frame_id, msg.encode(
        {s.name: 0 for s in msg.signals}), 7))
    frame[-1] ^= 0x01
    assert not e2e.check(msg.frame_id, frame)


# --- the plants' names and the scenarios' values ----------------------------------------------


def _plants() -> list:
    from firmware_sim.plants import PLANTS

    return [factory() for factory in PLANTS.values()]


def _drive_signals(database: Database) -> dict[str, Signal]:
    return {s.name: s for m in database.messages if _is_drive(m) for s in m.signals
            if s.name not in HEADER}


def _database_of(plant) -> Database:
    path = DBC_DIR / plant.dbc
    if not path.is_file():
        pytest.skip(f"{plant.dbc} (plant {plant.name}) has not landed in dbc/ yet")
    return cantools.database.load_file(path, strict=True)


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
    return sorted((REPO / "firmware_sim" / "scenarios").glob("*.yaml"))


def _scenarios_of(plant: str) -> list[Path]:
    import yaml

    return [p for p in _scenarios() if yaml.safe_load(p.read_text()).get("plant") == plant]


@pytest.mark.parametrize("scenario_path", _scenarios(), ids=_stem)
def test_scenario_values_stay_inside_the_signal_ranges(scenario_path: Path) -> None:
    from firmware_sim.scenario import load_scenario
    from firmware_sim.simulate import simulate

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
            message = database.get_message_by_frame_id(where["message"])
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


@pytest.mark.parametrize("config", _configs_of_profile_dbcs(), ids=_stem)
@pytest.mark.parametrize("scenario_path", _scenarios_of("dc_motor"), ids=_stem)
def test_scenario_values_stay_inside_the_mapped_signal_ranges(config: Path,
                                                              scenario_path: Path) -> None:
    """Every shipped DC motor scenario's values (faults and noise included), in the signals a
    profile's monitor config maps them to, stay inside each signal's range."""
    from firmware_sim.scenario import load_scenario
    from firmware_sim.simulate import simulate

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
    assert dbc_package.path("motor_drive") == dbc_package.path("motor_drive.dbc")
    shipped = dbc_package.path("motor_drive")
    assert shipped.read_bytes() == (DBC_DIR / "motor_drive.dbc").read_bytes()
    assert isinstance(dbc_package.load("motor_drive"), Database)


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
        p for p in find_namespace_packages(where=str(REPO), include=["canfdi*", "firmware_sim*"])
        if "__pycache__" not in p.split(".")
    }
    # The list is explicit (find cannot rename dbc/ to canfdi.dbc), so a new subpackage must be
    # added by hand or it silently drops out of the wheel.
    assert found | {"canfdi.dbc"} <= listed, sorted(found - listed)


# The shipped scenario each profile config is written for.
CONFIG_SCENARIOS = {"dc_motor_cia402": "dc_motor_consecutive_cia402",
                    "dc_motor_float": "dc_motor_consecutive_float",
                    "dc_motor_two_drives_cia402": "dc_motor_two_drives_cia402"}
# CANopen's predefined connection set: NMT, SYNC + EMCY, TIME, PDOs, SDOs, heartbeat, LSS.
CANOPEN_IDS = {0x000, *range(0x080, 0x100), 0x100, *range(0x181, 0x580), *range(0x581, 0x680),
               *range(0x701, 0x780), 0x7E4, 0x7E5}


def _frame_id(template: str | None, dbc_id: int, node: int | None) -> int:
    if template is None or node is None:
        return dbc_id
    return int(eval(template, {"__builtins__": {}}, {"id": dbc_id, "node": node}))


@pytest.mark.parametrize("config", _configs_of_profile_dbcs(), ids=_stem)
def test_monitor_config_reads_the_emulated_bus(config: Path) -> None:
    """The config, as docs/bus.md reads it, finds on the emulator's bus: every drive's IDs (the
    DBC's after bus.node.id), the clock's message, each model signal in the mapped message
    carrying that drive's values; its own frames at IDs no drive uses (nor, on CANopen, a
    predefined function code)."""
    from firmware_sim.emitter import frame_log
    from firmware_sim.scenario import load_scenario

    doc, mapped = _mapped(config)
    bus = doc["bus"]
    database = cantools.database.load_file(DBC_DIR / f"{bus['dbc']}.dbc", strict=True)
    template = (bus.get("node") or {}).get("id")
    drives = doc.get("drives") or [{"name": doc["name"], "node": None}]
    log = frame_log(load_scenario(CONFIG_SCENARIOS[config.stem]), duration=2.0)
    if drives[0]["node"] is not None:
        assert [d["node"] for d in drives] == [d.node for d in log.drives]
    on_bus = set(log.frames.id.tolist())
    expected = {_frame_id(template, m.frame_id, d["node"]) for m in database.messages
                for d in drives}
    assert expected == on_bus
    clock = bus["clock"]
    if clock["kind"] == "trigger":
        database.get_message_by_name(clock["message"])
    model = doc["signals"]
    remote = (log.frames.flags & 2) != 0
    for drive, run in zip(drives, log.drives, strict=True):
        for name, (message, sig) in mapped.items():
            fid = _frame_id(template, message.frame_id, drive["node"])
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
