"""Every bad config is one line naming the key and exit status 2 (the units' restart loop
stops on 2), through `run`, `replay` and `design`, and none costs memory or time out of
proportion to the file (issue 27): alias bombs, huge windows and matrices, template
arithmetic, non-finite or absurd entries, DBCs with one ID twice or overlapping signals."""

from __future__ import annotations

import logging
import re
import textwrap

import pytest

from canfdi.cli import main
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
BUS_ONLY = {"DBC: two messages of one ID", "missing DBC"}  # `design` reads no DBC


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
