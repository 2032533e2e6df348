"""docs/mcap.md names every topic, schema and field the recorder writes (docs match code)."""

from canfdi.io.schemas import (
    SCHEMAS,
    TOPIC_RESIDUALS,
    TOPIC_SAMPLES,
    residual_schema,
    sample_schema,
)
from tests.conftest import REPO


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
