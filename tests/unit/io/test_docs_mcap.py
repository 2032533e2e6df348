"""docs/mcap.md names every topic, schema and field the recorder writes (docs match code)."""

import numpy as np

from canfdi.io.schemas import (
    SCHEMAS,
    TOPIC_RESIDUALS,
    TOPIC_SAMPLES,
    residual_schema,
    sample_schema,
)
from tests.conftest import REPO


def test_every_row_topic_ros2_type_and_field_is_documented():
    """The row topics' default encoding: each ROS 2 type and every field of its definition."""
    from canfdi.io.cdr import CdrDecoder
    from canfdi.io.rowencodings import CdrRows
    from canfdi.io.rowtopics import ROW_LAYOUTS

    text = (REPO / "docs" / "mcap.md").read_text()
    for topic in (TOPIC_SAMPLES, TOPIC_RESIDUALS):
        rows = CdrRows(ROW_LAYOUTS[topic])
        schema, data = rows.encode(tuple([f"n{i}"] for i in range(len(rows.layout.names))),
                                   "left", np.array([1]), np.zeros((1, len(rows.layout.ints))),
                                   np.zeros((1, len(rows.layout.groups))))
        assert f"`{schema.name}`" in text, topic
        for field in CdrDecoder(schema.data.decode())(data[0].tobytes()):
            assert f"`{field}`" in text, (topic, field)


def test_every_topic_schema_and_field_is_documented():
    text = (REPO / "docs" / "mcap.md").read_text()
    schemas = {**SCHEMAS,
               TOPIC_SAMPLES: ("canfdi.Sample", sample_schema(["u0"], ["z0"])),
               TOPIC_RESIDUALS: ("canfdi.Residuals", residual_schema(["r0"]))}
    for topic, (name, schema) in schemas.items():
        assert schema["title"] == name
        assert f"`{topic}`" in text and f"`{name}`" in text, topic
        for field in schema["properties"]:
            assert f"`{field}`" in text, (topic, field)
