"""canfdi.tools.identify's writing side: the identified config as an edit of the user's file,
the report's JSON form, and the check that no log holds injected faults."""

import json
from pathlib import Path

import numpy as np
import yaml

from canfdi.config import load_config
from canfdi.io.writer import McapRecorder
from canfdi.tools.configdoc import ConfigDocument
from canfdi.tools.identify import Identification, config_document, first_faulty_log, jsonable
from tests.conftest import REPO

CONFIG = REPO / "deploy" / "config" / "servo_axis_odrive.yaml"


def _identification(updates: dict) -> Identification:
    return Identification(config=load_config(CONFIG, allow_unidentified=True), document={},
                          updates=updates, header=["Identified from the test."], report={})


def test_the_identified_config_is_the_users_file_with_the_learned_sections(tmp_path):
    document = ConfigDocument.load(CONFIG)
    out = tmp_path / "sub" / "servo.yaml"
    text = config_document(_identification({"noise.measurement": [0.1, 0.2, 0.3, 0.4],
                                             "model.identify": None}),
                           document, CONFIG, [Path("a.log"), Path("b.log")], out,
                           "2026-01-02 03:04 UTC").dump()
    lines = text.splitlines()
    assert lines[:2] == ["# canfdi identify, 2026-01-02 03:04 UTC: servo_axis_odrive.yaml + "
                         "a.log, b.log -> servo.yaml", "# Identified from the test."]
    assert "# An ODrive-like servo axis" in text  # the user's own comments stay
    data = yaml.safe_load(text)
    assert data["noise"]["measurement"] == [0.1, 0.2, 0.3, 0.4]
    assert "identify" not in (data.get("model") or {})
    assert data["bus"]["dbc"] == "servo_axis_float"  # a shipped DBC name is not a path


def test_a_printed_config_says_it_went_to_stdout():
    text = config_document(_identification({}), ConfigDocument.load(CONFIG), CONFIG,
                           [Path("a.log")], None, "when").dump()
    assert text.splitlines()[0].endswith("a.log -> stdout")


def test_the_reports_numbers_are_json():
    report = {"poles": [0.5 + 0.25j], "gain": np.array([[1.0, 2.0]]), "path": Path("x")}
    assert json.loads(json.dumps(report, default=jsonable)) == {
        "poles": [[0.5, 0.25]], "gain": [[1.0, 2.0]], "path": "x"}


def test_the_first_log_with_injected_faults_is_named(tmp_path):
    healthy = tmp_path / "healthy.mcap"
    McapRecorder(healthy, metadata={"version": "test"}).close()
    faulty = tmp_path / "faulty.mcap"
    truth = [{"target": "sensor", "index": 2, "name": "Vel_Estimate", "onset": 12.5}]
    McapRecorder(faulty, metadata={"truth_json": json.dumps(truth)}).close()
    candump = tmp_path / "other.log"
    candump.write_text("")
    assert first_faulty_log([healthy, candump]) is None
    assert first_faulty_log([healthy, faulty, candump]) == (faulty, truth)
