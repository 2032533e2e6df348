"""canfdi.tools.configdoc: a config edited the way its user wrote it (issue 26). The shipped
configs load, read as PyYAML reads them and dump byte for byte; after the tools' edits every
comment and hex literal is still there and the values set are what canfdi reads; relative DBC
paths follow the file to its new folder; every float written reads back as a float."""

import dataclasses
import difflib
import math
import re
from pathlib import Path

import numpy as np
import pytest
import yaml
from hypothesis import given
from hypothesis import strategies as st

from canfdi import methods
from canfdi.bus.dbc import load_dbc
from canfdi.config import parse_config
from canfdi.core.noise import NoiseEstimate
from canfdi.tools.calibrate import Calibration, calibrated_document, config_document
from canfdi.tools.configdoc import ConfigDocument, names_file
from tests.conftest import REPO

SHIPPED = sorted((REPO / "deploy" / "config").glob("*.yaml"))
IDS = [p.stem for p in SHIPPED]
# monitor configs (a model with matrices), not the templates `canfdi identify` fills in
MONITORS = [p for p in SHIPPED if "A" in (yaml.safe_load(p.read_text())["model"] or {})]
MONITOR_IDS = [p.stem for p in MONITORS]
COMMENT = re.compile(r"(?:^|\s)(#.*)$")


def comments(text: str) -> list[str]:
    """Every comment of a YAML text (none of the shipped configs has a # in a string)."""
    return [m.group(1).rstrip() for line in text.splitlines() if (m := COMMENT.search(line))]


def hex_lines(text: str) -> list[str]:
    """The value part of every line that writes a hex literal."""
    values = (COMMENT.sub("", line).rstrip() for line in text.splitlines())
    return [v for v in values if re.search(r"\b0x[0-9A-Fa-f]+\b", v)]


def assert_same(a, b, where="config"):
    """Field by field, arrays exactly."""
    if dataclasses.is_dataclass(a) and not isinstance(a, type):
        assert type(a) is type(b), where
        for f in dataclasses.fields(a):
            assert_same(getattr(a, f.name), getattr(b, f.name), f"{where}.{f.name}")
    elif isinstance(a, np.ndarray):
        np.testing.assert_array_equal(a, b, err_msg=where)
    elif isinstance(a, dict):
        assert isinstance(b, dict) and list(a) == list(b), where
        for key in a:
            assert_same(a[key], b[key], f"{where}.{key}")
    elif isinstance(a, list | tuple):
        assert type(a) is type(b) and len(a) == len(b), where
        for i, (x, y) in enumerate(zip(a, b, strict=True)):
            assert_same(x, y, f"{where}[{i}]")
    else:
        assert a == b or (a != a and b != b), f"{where}: {a!r} != {b!r}"


@pytest.mark.parametrize("path", SHIPPED, ids=IDS)
def test_plain_is_what_pyyaml_reads(path):
    plain = ConfigDocument.load(path).plain()
    assert plain == yaml.safe_load(path.read_text())
    if path in MONITORS:
        parse_config(plain, path)


@pytest.mark.parametrize("path", SHIPPED, ids=IDS)
def test_an_unedited_config_is_written_byte_for_byte(path):
    assert ConfigDocument.load(path).dump() == path.read_text()


def _scaled(matrix, factor):
    return [[x * factor for x in row] for row in matrix]


@pytest.mark.parametrize("path", MONITORS, ids=MONITOR_IDS)
def test_set_keeps_every_comment_and_hex_literal_and_sets_the_values(path):
    text = path.read_text()
    plain = yaml.safe_load(text)
    q = len(plain["signals"]["outputs"])
    noise = [0.01 * (i + 1) / 3 for i in range(q)]  # thirds: the 10-digit rounding shows
    model = dict(plain["model"])
    model["A"] = _scaled(model["A"], 0.5)
    model["B"] = _scaled(model["B"], 1 / 3)
    doc = ConfigDocument.load(path)
    doc.set("noise.measurement", noise)
    doc.set("model", model)
    out = doc.dump()
    for comment in comments(text):
        assert comment in out, comment
    for line in hex_lines(text):
        assert line in out, line
    config = parse_config(yaml.safe_load(out), path)
    rounded = [float(f"{x:.10g}") for x in noise]
    np.testing.assert_array_equal(config.design.measurement_std, rounded)
    np.testing.assert_allclose(config.model.A, _scaled(plain["model"]["A"], 0.5), rtol=1e-9)
    np.testing.assert_allclose(config.model.B, _scaled(plain["model"]["B"], 1 / 3), rtol=1e-9)
    # the rest of the config is what it was
    before = parse_config(plain, path)
    assert_same(dataclasses.replace(config, model=before.model,
                                    design=before.design), before)


def test_a_matrix_is_written_one_row_per_line_and_a_one_line_matrix_stays_on_one_line():
    doc = ConfigDocument.parse("model:\n  A: [[1, 2], [3, 4]]   # as the user wrote it\n")
    doc.set("model.B", [[0.5], [0.25]])
    doc.set("model.C", [[1, 0], [0, 1], [1, 1]])
    assert doc.dump() == ("model:\n"
                          "  A: [[1, 2], [3, 4]]   # as the user wrote it\n"
                          "  B: [[0.5],\n"
                          "      [0.25]]\n"
                          "  C: [[1, 0],\n"
                          "      [0, 1],\n"
                          "      [1, 1]]\n")


def test_an_existing_key_keeps_its_place_and_comments_a_new_one_goes_last():
    text = ("a: 1\n"
            "# about b\n"
            "b: 2   # b's own\n"
            "# about c\n"
            "c: {x: 1, y: 0x10}\n")
    doc = ConfigDocument.parse(text)
    doc.set("b", [1.5, 2.5], comment="set by the test")
    doc.set("c.x", 2)  # a flow mapping stays one, its hex literal too
    doc.set("d.e", "new")
    assert doc.dump() == ("a: 1\n"
                          "# about b\n"
                          "# set by the test\n"
                          "b: [1.5, 2.5] # b's own\n"
                          "# about c\n"
                          "c: {x: 2, y: 0x10}\n"
                          "d:\n"
                          "  e: new\n")


def test_a_mapping_set_over_a_mapping_merges_so_unchanged_literals_stay():
    text = "bus:\n  monitor:\n    base: 0x7C0   # node 62\n  name: 'quoted'\n  old: 1\n"
    doc = ConfigDocument.parse(text)
    doc.set("bus", {"monitor": {"base": 0x7C0}, "name": "quoted", "new": 2})
    assert doc.dump() == ("bus:\n  monitor:\n    base: 0x7C0   # node 62\n"
                          "  name: 'quoted'\n  new: 2\n")


def test_replacing_a_block_value_keeps_the_comments_about_what_follows():
    text = ("noise:\n"
            "  measurement:   # per sensor\n"
            "  - 0.01\n"
            "  - 0.02   # the second\n"
            "  # about process\n"
            "  process: 0.0\n")
    doc = ConfigDocument.parse(text)
    doc.set("noise.measurement", [0.03, 0.04])
    assert doc.dump() == ("noise:\n"
                          "  measurement: [0.03, 0.04] # per sensor\n"
                          "  # about process\n"
                          "  process: 0.0\n")
    doc.set("noise.measurement", {"i_f": 0.03})  # and from a scalar to a block mapping
    doc.set("noise.process", {"x": 1})
    assert doc.dump() == ("noise:\n"
                          "  measurement:   # per sensor\n"
                          "    i_f: 0.03\n"
                          "  # about process\n"
                          "  process:\n"
                          "    x: 1\n")


def test_delete_keeps_the_comments_about_what_follows():
    text = ("top:\n"
            "  a: 1\n"
            "  b: 2   # b's own, deleted with it\n"
            "  # about c\n"
            "  c: 3\n"
            "  d:\n"
            "    x: 1   # inside d\n"
            "# about next\n"
            "next: 1\n")
    doc = ConfigDocument.parse(text)
    doc.delete("top.b")
    doc.delete("top.d")
    doc.delete("top.missing")
    doc.delete("nowhere.at.all")
    assert doc.dump() == ("top:\n"
                          "  a: 1\n"
                          "  # about c\n"
                          "  c: 3\n"
                          "# about next\n"
                          "next: 1\n")
    doc.delete("top.a")  # the first key: its lines go above the next one
    assert doc.dump().startswith("top:\n  # about c\n  c: 3\n")


def test_a_new_last_key_goes_above_the_comments_about_the_next_section():
    doc = ConfigDocument.parse("model:\n  A: [[1]]\n  # about signals\nsignals: {}\n")
    doc.set("model.D", [[0]])
    assert doc.dump() == "model:\n  A: [[1]]\n  D: [[0]]\n  # about signals\nsignals: {}\n"


def test_header_lines_come_first_above_the_users_header():
    path = SHIPPED[0]
    doc = ConfigDocument.load(path)
    doc.header(["Calibrated by a test", "on a second line"])
    out = doc.dump()
    assert out == ("# Calibrated by a test\n# on a second line\n" + path.read_text())
    assert ConfigDocument.parse(out).plain() == yaml.safe_load(path.read_text())


def test_a_document_start_and_what_is_above_it_stay():
    text = "# above\n%YAML 1.1\n---\n# below\na: 1\n"
    doc = ConfigDocument.parse(text)
    assert doc.dump() == text
    doc.header(["first"])
    assert doc.dump() == "# first\n" + text


@pytest.mark.parametrize("value", [1e7, 1.5e-5, 1e-5, 1e16, 1e22, -2.5e-300, 0.1 + 0.2, 1 / 3,
                                   123456789012.0, 5e-324, -0.0, math.inf, -math.inf])
def test_every_float_written_reads_back_as_that_float(value):
    doc = ConfigDocument.parse("x: 0\n")
    doc.set("x", value)
    doc.set("y", [value, value])
    read = yaml.safe_load(doc.dump())
    expected = float(f"{value:.10g}")
    assert type(read["x"]) is float and read["x"] == expected
    assert read["y"] == [expected, expected]
    assert "e" not in doc.dump() or re.search(r"\d\.\d*e[+-]\d", doc.dump())


@given(st.floats(allow_nan=False))
def test_any_float_round_trips_through_pyyaml_at_ten_digits(value):
    doc = ConfigDocument.parse("x: 0\n")
    doc.set("x", value)
    read = yaml.safe_load(doc.dump())["x"]
    assert type(read) is float and read == float(f"{value:.10g}")


def test_nan_and_numpy_values_are_written_as_plain_numbers():
    doc = ConfigDocument.parse("x: 0\n")
    doc.set("x", np.array([[np.float32(0.5), np.nan]]))
    doc.set("n", np.int64(7))
    read = yaml.safe_load(doc.dump())
    assert read["x"][0][0] == 0.5 and math.isnan(read["x"][0][1]) and read["n"] == 7
    with pytest.raises(TypeError):
        doc.set("z", object())


@pytest.mark.parametrize("text", ["on", "yes", "No", "1:30", "0x10", "1.0e9", "~", "null", "3",
                                  "2024-01-01", "plain words"])
def test_strings_are_read_back_as_strings(text):
    doc = ConfigDocument.parse("s: x\n")
    doc.set("s", text)
    assert yaml.safe_load(doc.dump())["s"] == text


def test_long_lists_and_lists_of_mappings_are_block_style():
    doc = ConfigDocument.parse("a: 1\n")
    doc.set("long", list(range(17)))
    doc.set("entries", [{"output": "T1", "b": [0.5]}])
    out = doc.dump()
    assert "long:\n- 0\n" in out and "entries:\n- output: T1\n  b: [0.5]\n" in out
    assert yaml.safe_load(out)["long"] == list(range(17))


def test_relocate_paths_points_at_the_same_files_from_the_output(tmp_path):
    dbc = (REPO / "dbc" / "motor_drive.dbc").read_text()
    (tmp_path / "drive.dbc").write_text(dbc)
    (tmp_path / "a" / "dbc").mkdir(parents=True)
    (tmp_path / "a" / "dbc" / "monitor.dbc").write_text(
        (REPO / "dbc" / "canfdi_monitor.dbc").read_text())
    text = (REPO / "deploy" / "config" / "dc_motor.yaml").read_text().replace(
        "  dbc: motor_drive\n", "  dbc: ../drive.dbc   # the vendor's\n"
                                "  monitor: {dbc: 'dbc/monitor.dbc', base: 0x7C0}\n")
    source = tmp_path / "a" / "monitor.yaml"
    source.write_text(text)
    out = tmp_path / "b" / "c" / "out.yaml"
    doc = ConfigDocument.load(source)
    doc.relocate_paths(source, out)
    doc.write(out)
    written = out.read_text()
    # the comment keeps its column where the longer path leaves room for it, else one space
    assert re.search(r"\n  dbc: \.\./\.\./drive\.dbc +# the vendor's\n", written)
    assert "monitor: {dbc: '../../a/dbc/monitor.dbc', base: 0x7C0}" in written  # quotes kept
    config = parse_config(yaml.safe_load(written), out)
    assert Path(load_dbc(config.bus.dbc, out)[1]).resolve() == (tmp_path / "drive.dbc").resolve()
    assert (Path(load_dbc(config.bus.monitor.dbc, out, "bus.monitor.dbc")[1]).resolve()
            == (tmp_path / "a" / "dbc" / "monitor.dbc").resolve())
    # from the same folder, nothing changes (not even ./)
    same = ConfigDocument.parse(text.replace("../drive.dbc", "./../drive.dbc"))
    same.relocate_paths(source, tmp_path / "a" / "other.yaml")
    assert "dbc: ./../drive.dbc" in same.dump()


@pytest.mark.parametrize("value", ["motor_drive", "motor_drive.dbc", "/abs/drive.dbc",
                                   "~/drive.dbc"])
def test_relocate_paths_leaves_shipped_names_and_absolute_paths(tmp_path, value):
    doc = ConfigDocument.parse(f"bus:\n  dbc: {value}\n")
    doc.relocate_paths(tmp_path / "a" / "x.yaml", tmp_path / "b" / "c" / "y.yaml")
    assert doc.dump() == f"bus:\n  dbc: {value}\n"


def test_a_shipped_name_is_told_from_a_path_as_load_dbc_does():
    assert not names_file("motor_drive") and not names_file("motor_drive.dbc")
    assert names_file("dbc/motor_drive.dbc") and names_file("./motor_drive")
    assert names_file("no_such_shipped_dbc")


def test_errors_name_the_file_and_the_position(tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text("a: 1\nb: [1, 2\nc: 3\n")
    with pytest.raises(ValueError, match=r"bad\.yaml: invalid YAML at line 3, column 2"):
        ConfigDocument.load(bad)
    with pytest.raises(ValueError, match="file not found"):
        ConfigDocument.load(tmp_path / "none.yaml")
    with pytest.raises(ValueError, match="expected a mapping"):
        ConfigDocument.parse("- 1\n")
    with pytest.raises(ValueError, match="a: not a mapping"):
        ConfigDocument.parse("a: 1\n").set("a.b", 2)


def _calibration(path: Path, std: np.ndarray) -> Calibration:
    """What `calibrate` returns for a config, with a made-up noise ``std``."""
    doc = yaml.safe_load(path.read_text())
    config = parse_config(doc, path)
    q = len(config.outputs)
    noise = NoiseEstimate(std=std, covariance=np.diag(std**2), identifiable=np.ones(q, bool),
                          seen=np.ones(q, bool), std_error=std / 10, windows=1000, s=4)
    return Calibration(logs=["healthy.mcap"], samples=9000, noise=noise,
                       prior_std=np.full(q, 0.01), outputs=list(config.outputs), residuals=[],
                       config=config, document=calibrated_document(doc, config, std))


@pytest.mark.parametrize("path", MONITORS, ids=MONITOR_IDS)
def test_the_calibrated_config_written_is_calibrated_document_value_for_value(path,
                                                                              tmp_path):
    q = len(yaml.safe_load(path.read_text())["signals"]["outputs"])
    std = np.linspace(0.0123456, 0.0234567, q)
    calibration = _calibration(path, std)
    out = tmp_path / "out" / "calibrated.yaml"
    text = config_document(calibration, ConfigDocument.load(path), path, out,
                           "2024-01-01 00:00 UTC").dump()
    assert text.startswith("# Calibrated by `canfdi calibrate` on 2024-01-01 00:00 UTC from "
                           "9000 healthy\n# samples of 1 log(s): healthy.mcap.\n")
    original = path.read_text()
    for comment in comments(original):
        assert comment in text, comment
    for line in hex_lines(original):
        assert line in text, line
    # no other line changes: the method's section is merged, its unchanged entries stay
    removed = [line for line in difflib.ndiff(original.splitlines(), text.splitlines())
               if line.startswith("- ")]
    assert removed and all("measurement" in line or "residual_std" in line
                           for line in removed), removed
    written = parse_config(yaml.safe_load(text), out)
    assert_same(written, parse_config(calibration.document, out))
    np.testing.assert_allclose(written.design.measurement_std, std, rtol=1e-3)
    section = methods.get(written.method).section
    if methods.get(written.method).with_noise is not None:  # its noise level follows
        np.testing.assert_allclose(yaml.safe_load(text)[section]["residual_std"], std,
                                   rtol=1e-3)
