"""Every bad config is one line naming the key and exit status 2 (the units' restart loop
stops on 2), through `run`, `replay` and `design`, and none costs memory or time out of
proportion to the file (issue 27): alias bombs, huge windows and matrices, template
arithmetic, non-finite or absurd entries, DBCs with one ID twice or overlapping signals."""

from __future__ import annotations

import logging
import re
import textwrap

import pytest

from tests.cli import canfdi_main as main
from tests.conftest import REPO

CONFIGS = REPO / "deploy" / "config"
SINGLE = (CONFIGS / "dc_motor.yaml").read_text()
TWO = (CONFIGS / "dc_motor_two_drives_cia402.yaml").read_text()
TEMPLATE = '"(id & ~0x7F) | node"'
BOMB = ("[&a [lol,lol,lol,lol,lol,lol,lol,lol,lol], "
        + ", ".join(f"&{c} [" + ",".join(["*" + p] * 9) + "]"
                    for p, c in zip("abcdefgh", "bcdefghi", strict=True)) + "]")
NESTED = ("[[&z [1,1,1,1,1,1,1,1,1], &y [*z,*z,*z,*z,*z,*z,*z,*z,*z], "
          "&x [*y,*y,*y,*y,*y,*y,*y,*y,*y], &w [*x,*x,*x,*x,*x,*x,*x,*x,*x], *w], ")


@pytest.fixture(autouse=True)
def _own_log_handlers():
    """`run` points the root logger at the stderr of its call: give it back afterwards, so
    that the next test's captured stderr is not a closed one."""
    root = logging.getLogger()
    handlers, level = list(root.handlers), root.level
    yield
    root.handlers[:] = handlers
    root.setLevel(level)


def _a(text: str, first_row: str) -> str:
    return text.replace("  A: [[0.8825, 0, 0],", f"  A: [{first_row},", 1)


def _dbc(tmp_path, body: str, config: str = SINGLE) -> str:
    """The single-drive config on a copy of its DBC with ``body`` appended."""
    from canfdi import dbc as dbc_files

    text = dbc_files.path("motor_drive").read_text()
    text = text.replace("BO_ 261 ", textwrap.dedent(body).lstrip() + "\nBO_ 261 ", 1)
    (tmp_path / "drive.dbc").write_text(text)
    return re.sub(r"dbc: motor_drive\b", "dbc: drive.dbc", config, count=1)


CASES: dict[str, tuple] = {
    # name: (config text or a function of tmp_path, the key the error must name)
    "alias bomb in a name": (TWO.replace("    message: SYNC ", f"    message: {BOMB} ", 1),
                             "config"),
    "alias bomb in a matrix": (_a(SINGLE, "[0.8825, 0, 0]").replace(
        "  A: [", f"  X: {BOMB}\n  A: [", 1), "config"),
    "alias nested in a matrix": (SINGLE.replace("  A: [[0.8825, 0, 0],", "  A: " + NESTED, 1),
                                 "model.A"),
    "window 100000": (SINGLE.replace("actuator_window: 8 ", "actuator_window: 100000 ", 1),
                      "design.actuator_window"),
    "negative window": (SINGLE.replace("sensor_window: 4 ", "sensor_window: -1 ", 1),
                        "design.sensor_window"),
    "max window 10^6": (SINGLE.replace("max_window: 10", "max_window: 1000000", 1),
                        "design.max_window"),
    "A entry 1e308": (_a(SINGLE, "[1e308, 0, 0]"), "model.A[0][0]"),
    "A entry nan": (_a(SINGLE, "[.nan, 0, 0]"), "model.A[0][0]"),
    "A entry inf": (_a(SINGLE, "[0.8825, .inf, 0]"), "model.A[0][1]"),
    "A entry text": (_a(SINGLE, "[0.8825, x, 0]"), "model.A"),
    "A 300 columns": (_a(SINGLE, "[" + ", ".join(["0"] * 300) + "]"), "model.A"),
    "A wrong shape": (_a(SINGLE, "[0.8825, 0]"), "model.A"),
    "shift by 10^11": (TWO.replace(TEMPLATE, '"id << 100000000000"'), "bus.node.id"),
    "100000 tildes": (TWO.replace(TEMPLATE, '"' + "~" * 100_000 + 'id"'), "bus.node.id"),
    "100000-term sum": (TWO.replace(TEMPLATE, '"' + "+".join(["1"] * 100_000) + '"'),
                        "bus.node.id"),
    "division by zero at node 2": (
        TWO.replace(TEMPLATE, '"(id & ~0x7F) | (4 // (node - 2))"'), "bus.node.id"),
    "template beyond 29 bits": (TWO.replace(TEMPLATE, '"id << 40 | node"'), "bus.node.id"),
    "template calls a function": (TWO.replace(TEMPLATE, '"__import__(1)"'), "bus.node.id"),
    "template not a string": (TWO.replace(TEMPLATE, "[1, 2]"), "bus.node.id"),
    "deep brackets": (TWO.replace(TEMPLATE, '"' + "(" * 500 + "id" + ")" * 500 + '"'),
                      "bus.node.id"),
    "unknown top key": (SINGLE + "\nbogus: 1\n", "bogus"),
    "unknown clock": (SINGLE.replace("bus:", "bus:\n  clock: {kind: sundial}", 1),
                      "bus.clock.kind"),
    "YAML syntax": (SINGLE + "\n  : - [\n", "config"),
    "two drives one name": (TWO.replace("{name: right, node: 2}", "{name: left, node: 2}"),
                            "drives[1].name"),
    "DBC: two messages of one ID": (lambda tmp: _dbc(tmp, """
        BO_ 1025 EXTRA_A: 8 DRIVE
         SG_ X : 0|8@1+ (1,0) [0|255] "" MONITOR
        BO_ 1025 EXTRA_B: 8 DRIVE
         SG_ Y : 0|8@1+ (1,0) [0|255] "" MONITOR
        """), "bus.dbc"),
    "missing DBC": (re.sub(r"dbc: motor_drive\b", "dbc: nowhere.dbc", SINGLE, count=1),
                    "bus.dbc"),
}


def _sub(old: str, new: str, text: str = SINGLE) -> str:
    assert old in text, f"the shipped config changed: {old!r} is gone"
    return text.replace(old, new, 1)


_MATRIX_A = r"  A: \[\[0.8825, 0, 0\],\n      \[0, 0.6839, 0\],\n      \[0, 0, 0.9948\]\]"
CASES.update(
    {
        # Every section's keys: a wrong type, a value out of range, an unknown key, a shape.
        "dt zero": (_sub("  dt: 0.01 ", "  dt: 0 "), "model.dt"),
        "dt negative": (_sub("  dt: 0.01 ", "  dt: -0.01 "), "model.dt"),
        "dt text": (_sub("  dt: 0.01 ", "  dt: fast "), "model.dt"),
        "time continuous unknown": (_sub("  time: discrete", "  time: sideways"), "model.time"),
        "B wrong rows": (
            _sub(
                "  B: [[0.002235],\n      [0.0823],\n      [0]]",
                "  B: [[0.002235],\n      [0.0823]]",
            ),
            "model.B",
        ),
        "C wrong columns": (_sub("  C: [[1, 0, 0],", "  C: [[1, 0],"), "model.C"),
        "F wrong rows": (
            _sub("  F: [[0, 0],\n      [1, 0],\n      [0, 1]]", "  F: [[0, 0],\n      [1, 0]]"),
            "model.F",
        ),
        "A missing": (re.sub(_MATRIX_A + "\n", "", SINGLE), "model.A"),
        "A a scalar": (re.sub(_MATRIX_A, "  A: 3", SINGLE), "model.A"),
        "A empty": (re.sub(_MATRIX_A, "  A: []", SINGLE), "model.A"),
        "B entry nan": (_sub("  B: [[0.002235],", "  B: [[.nan],"), "model.B[0][0]"),
        "C entry 1e300": (_sub("  C: [[1, 0, 0],", "  C: [[1e300, 0, 0],"), "model.C[0][0]"),
        "F entry -inf": (_sub("  F: [[0, 0],", "  F: [[-.inf, 0],"), "model.F[0][0]"),
        "model not a mapping": (
            re.sub(r"model:\n(  .*\n|      .*\n)+", "model: 7\n", SINGLE),
            "model",
        ),
        "inputs count wrong": (_sub("  inputs: [V]", "  inputs: [V, W]"), "signals.inputs"),
        "outputs count wrong": (
            _sub("  outputs: [i_f, i_a, i_f_plus_i_a, omega_r]", "  outputs: [i_f, i_a]"),
            "signals.outputs",
        ),
        "duplicate output names": (
            _sub(
                "  outputs: [i_f, i_a, i_f_plus_i_a, omega_r]",
                "  outputs: [i_f, i_a, i_a, omega_r]",
            ),
            "signals.outputs",
        ),
        "unknown inputs count wrong": (
            _sub("  unknown_inputs: [phi1, phi2]", "  unknown_inputs: [phi1]"),
            "signals.unknown_inputs",
        ),
        "output not in the DBC": (
            _sub(
                "  outputs: [i_f, i_a, i_f_plus_i_a, omega_r]",
                "  outputs: [i_f, i_a, i_f_plus_i_a, speed]",
            ),
            "speed",
        ),
        "input name a number": (_sub("  inputs: [V]", "  inputs: [3]"), "signals.inputs"),
        "signals unknown key": (
            _sub("  inputs: [V]", "  inputs: [V]\n  extras: [x]"),
            "signals.extras",
        ),
        "noise negative": (
            _sub("  measurement: 0.01 ", "  measurement: -0.01 "),
            "noise.measurement",
        ),
        "noise text": (_sub("  measurement: 0.01 ", "  measurement: loud "), "noise.measurement"),
        "noise wrong length": (
            _sub("  measurement: 0.01 ", "  measurement: [0.01, 0.01] "),
            "noise.measurement",
        ),
        "noise nan": (_sub("  measurement: 0.01 ", "  measurement: .nan "), "noise.measurement"),
        "noise unknown key": (
            _sub("  process: 0.0", "  process: 0.0\n  quantum: 1"),
            "noise.quantum",
        ),
        "actuator window float": (
            _sub("actuator_window: 8 ", "actuator_window: 2.5 "),
            "design.actuator_window",
        ),
        "design unknown key": (
            _sub("  max_window: 10", "  max_window: 10\n  horizon: 5"),
            "design.horizon",
        ),
        "drift negative": (_sub("  drift: 0.5 ", "  drift: -0.5 "), "detection.drift"),
        "false alarm interval zero": (
            _sub("  false_alarm_interval: 1.0e9 ", "  false_alarm_interval: 0 "),
            "detection.false_alarm_interval",
        ),
        "detection a list": (
            _sub("detection:\n  drift: 0.5 ", "detection: [1]\nxdetection:\n  drift: 0.5 "),
            "detection",
        ),
        "min samples above max": (
            _sub("  min_samples: 10", "  min_samples: 5000"),
            "identification",
        ),
        "max samples huge": (
            _sub("  max_samples: 2000", "  max_samples: 1000000000000"),
            "identification.max_samples",
        ),
        "settle rel std negative": (
            _sub("  settle_rel_std: 0.005", "  settle_rel_std: -1"),
            "identification.settle_rel_std",
        ),
        "settle noise negative": (
            _sub("  settle_noise: 0.2", "  settle_noise: -0.2"),
            "identification.settle_noise",
        ),
        "identification unknown key": (
            _sub("  isolation_margin: 50.0", "  isolation_margin: 50.0\n  patience: 3"),
            "identification.patience",
        ),
        "rotate mib zero": (_sub("  rotate_mib: 256", "  rotate_mib: 0"), "recording.rotate_mib"),
        "keep days negative": (
            _sub("  rotate_minutes: 60", "  rotate_minutes: 60\n  keep_days: -3"),
            "recording.keep_days",
        ),
        "keep mib text": (
            _sub("  rotate_minutes: 60", "  rotate_minutes: 60\n  keep_mib: lots"),
            "recording.keep_mib",
        ),
        "row encoding unknown": (
            _sub("  rotate_minutes: 60", "  rotate_minutes: 60\n  row_encoding: xml"),
            "recording.row_encoding",
        ),
        "recording unknown key": (
            _sub("  rotate_minutes: 60", "  rotate_minutes: 60\n  rotate_hours: 1"),
            "recording.rotate_hours",
        ),
        "watchdog factor below 1": (SINGLE + "watchdog:\n  factor: 0.5\n", "watchdog.factor"),
        "watchdog enabled text": (SINGLE + "watchdog:\n  enabled: maybe\n", "watchdog.enabled"),
        "status period negative": (
            _sub("  status_period: 1.0", "  status_period: -1"),
            "bus.status_period",
        ),
        "bitrate text": (
            _sub("  status_period: 1.0", "  status_period: 1.0\n  bitrate: fast"),
            "bus.bitrate",
        ),
        "bus unknown key": (
            _sub("  status_period: 1.0", "  status_period: 1.0\n  baud: 500000"),
            "bus.baud",
        ),
        "bus a string": (re.sub(r"bus:\n(  .*\n)+", "bus: can0\n", SINGLE), "bus"),
        "method unknown": (SINGLE + "method: telepathy\n", "method"),
        "name empty": (_sub("name: dc_motor", "name: ''"), "name"),
        "name a list": (_sub("name: dc_motor", "name: [a]"), "name"),
        "description a number": (
            _sub("description: Shunt", "description: 5\nxdescription: Shunt"),
            "description",
        ),
        "document a list": ("- 1\n- 2\n", "config"),
        "empty document": ("", "config"),
        "a binary file": ("\x00\x01\x02\xff", "config"),
        "tabs in YAML": (SINGLE.replace("  drift: 0.5", "\tdrift: 0.5"), "config"),
        "duplicate key": (SINGLE + "name: again\n", "name"),
        "map of an unknown signal": (
            _sub("  status_period: 1.0", "  status_period: 1.0\n  map:\n    nosuch: {signal: X}"),
            "bus.map",
        ),
        "range inverted": (
            _sub(
                "  status_period: 1.0",
                "  status_period: 1.0\n  map:\n"
                "    V: {message: DRIVE_CMD, signal: V, range: [5, -5]}",
            ),
            "bus.map.V.range",
        ),
        "transmit text": (
            _sub("  status_period: 1.0", "  status_period: 1.0\n  transmit: perhaps"),
            "bus.transmit",
        ),
        "two drives without a template": (
            _sub("bus:", "drives: [{name: a, node: 1}, {name: b, node: 2}]\nbus:"),
            "bus.node.id",
        ),
        "node id negative": (
            TWO.replace("{name: right, node: 2}", "{name: right, node: -2}"),
            "drives[1].node",
        ),
        "node id huge": (
            TWO.replace("{name: right, node: 2}", "{name: right, node: 100000000000}"),
            "drives[1].node",
        ),
        "template unknown name": (TWO.replace(TEMPLATE, '"(id & ~0x7F) | nod"'), "bus.node.id"),
    }
)
BUS_ONLY = {"DBC: two messages of one ID", "missing DBC",  # `design` reads no DBC
            "output not in the DBC"}


def _write(tmp_path, name: str):
    text, key = CASES[name]
    if callable(text):
        text = text(tmp_path)
    path = tmp_path / "bad.yaml"
    path.write_text(text)
    return path, key


def test_the_cases_are_bad_only_where_they_say():
    # The base configs are good: each case's error is its own change.
    assert "motor_drive" in SINGLE and TEMPLATE in TWO
    assert "actuator_window: 8 " in SINGLE and "sensor_window: 4 " in SINGLE


@pytest.mark.parametrize("verb", ["design", "replay", "run"])
@pytest.mark.parametrize("name", sorted(CASES))
def test_a_bad_config_is_one_line_naming_the_key_and_exit_2(tmp_path, capsys, verb, name):
    if verb == "design" and name in BUS_ONLY:
        pytest.skip("design analyses the model; it reads no DBC")
    path, key = _write(tmp_path, name)
    log = REPO / "tests" / "data" / "python-can" / "logfile.asc"
    argv = {"design": ["design", str(path)],
            "replay": ["replay", str(log), "--config", str(path), "--no-progress"],
            "run": ["run", "--config", str(path), "--duration", "0.1", "--no-record",
                    "--no-live", "--quiet"]}[verb]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    assert f"{key}" in err[0] and "config error" in err[0]
    assert len(err[0]) <= 500


def test_overlapping_signals_of_a_mapped_message_are_named(tmp_path, capsys):
    # A second signal laid over the bits the model's armature voltage V is read from.
    from canfdi import dbc as dbc_files

    text = dbc_files.path("motor_drive").read_text()
    assert " SG_ V : 16|16@1-" in text, "the DBC's layout changed: update the test"
    text = text.replace(" SG_ V : 16|16@1-",
                        ' SG_ SHADOW : 16|8@1+ (1,0) [0|255] "" FDI\n SG_ V : 16|16@1-', 1)
    (tmp_path / "drive.dbc").write_text(text)
    config = re.sub(r"dbc: motor_drive\b", "dbc: drive.dbc", SINGLE, count=1)
    (tmp_path / "bad.yaml").write_text(config)
    assert main(["replay", str(REPO / "tests" / "data" / "python-can" / "logfile.asc"),
                 "--config", str(tmp_path / "bad.yaml"), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert "SHADOW" in err and "overlap" in err and "bus.dbc" in err
