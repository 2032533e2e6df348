"""docs/foxglove-layout.json: every message path of its panels names a number field of the demo
log's channels (by their JSON schemas, and the row topics' ROS 2 definitions as Foxglove's
mcap-ros2-support parses them), in the message path syntax of Foxglove's lineage (a topic,
then ``.name`` or ``."quoted name"`` parts)."""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Any

from mcap.reader import make_reader
from mcap.records import Schema

from tests.cli import canfdi_main as main

LAYOUT = Path(__file__).resolve().parents[2] / "docs" / "foxglove-layout.json"
# Lichtblick's message-path grammar: id -> [a-zA-Z0-9_-]+, or a double-quoted string.
_PART = re.compile(r'\.(?:([A-Za-z0-9_-]+)|"((?:[^"\\]|\\.)*)")')


def split_path(path: str) -> tuple[str, list[str]]:
    topic, _, rest = path.partition(".")
    fields, pos = [], 0
    rest = "." + rest if rest else ""
    while pos < len(rest):
        match = _PART.match(rest, pos)
        assert match, f"not a message path: {path!r} at {rest[pos:]!r}"
        fields.append(match.group(1) if match.group(1) is not None else
                      json.loads(f'"{match.group(2)}"'))
        pos = match.end()
    return topic, fields


def field_tree(schema: Schema) -> dict[str, Any]:
    """{field: its subtree, or "number" or another type} of a channel's schema."""
    if schema.encoding == "jsonschema":
        def walk(node: dict[str, Any]) -> Any:
            if "properties" in node:
                return {key: walk(value) for key, value in node["properties"].items()}
            return node.get("type")
        return walk(json.loads(schema.data))
    assert schema.encoding == "ros2msg", schema.encoding
    from mcap_ros2._dynamic import _for_each_msgdef

    types: dict[str, dict[str, str]] = {}
    _for_each_msgdef(schema.name, schema.data.decode(), lambda name, short, spec: types.update(
        {short: {f.name: f"{f.type.pkg_name}/{f.type.type}" if f.type.pkg_name
                 else f.type.type for f in spec.fields}}))

    def expand(name: str) -> Any:
        return {key: expand(kind) if kind in types else
                ("number" if kind in ("float64", "float32") else kind)
                for key, kind in types[name].items()}
    return expand(schema.name.replace("/msg/", "/"))


def test_every_panel_path_is_a_field_of_the_demo_log(tmp_path: Path) -> None:
    log = tmp_path / "demo.mcap"
    assert main(["demo", "--no-live", "--json", "-o", str(log)]) == 0
    with open(log, "rb") as f:
        summary = make_reader(f).get_summary()
    schemas = {c.topic: summary.schemas[c.schema_id] for c in summary.channels.values()}
    assert {schemas[t].encoding for t in ("/canfdi/samples", "/canfdi/residuals")} == {
        "ros2msg"}
    trees = {topic: field_tree(schema) for topic, schema in schemas.items()}
    layout = json.loads(LAYOUT.read_text())
    panels = layout["configById"]
    paths = [p["value"] for config in panels.values() for p in config.get("paths", [])]
    assert len(paths) >= 10
    for path in paths:
        topic, fields = split_path(path)
        node = trees[topic]
        for field in fields:
            assert field in node, f"{path}: no {field!r}"
            node = node[field]
        assert node == "number", path
    topics = {c.get("topicPath") or c.get("topicToRender") for c in panels.values()} - {None}
    assert topics == {"/canfdi/events", "/canfdi/log"} and topics <= set(schemas)
    assert schemas["/canfdi/log"].name == "foxglove.Log"

    def leaves(node):
        return [node] if isinstance(node, str) else leaves(node["first"]) + leaves(
            node["second"])

    assert sorted(leaves(layout["layout"])) == sorted(panels)


def test_demo_log_time_is_the_drive_time(tmp_path: Path) -> None:
    """A 40 s drive spans 40 s of log time on every topic, the monitor's own frames (sent at
    full speed, in well under 40 s of wall time) and log lines included."""
    from canfdi.io.reader import read_frames, read_log

    log = tmp_path / "demo.mcap"
    assert main(["demo", "--no-live", "--json", "-o", str(log)]) == 0
    frames = read_frames(log)
    start, end = int(frames.t_ns.min()), int(frames.t_ns.max())
    assert 39.9e9 < end - start < 40.1e9
    sent = frames.t_ns[frames.status == "sent"]
    assert len(sent) > 5 and start <= sent.min() and sent.max() <= end
    times: dict[str, list[int]] = {}
    for topic, t, message in read_log(log):
        times.setdefault(topic, []).append(t)
        stamp = message.get("timestamp")  # the row topics' ROS 2 rows carry t_ns
        own = message["t_ns"] if stamp is None else stamp["sec"] * 10**9 + stamp["nsec"]
        assert own == t
    for topic, ts in times.items():
        assert start <= min(ts) and max(ts) <= end, topic
    samples = times["/canfdi/samples"]
    assert len(samples) == 4000 and 39.9e9 < samples[-1] - samples[0] < 40.1e9
    # Three faults detected and accepted, and the refinements of their estimates.
    assert len(times["/canfdi/log"]) == len(times["/canfdi/events"]) >= 6
