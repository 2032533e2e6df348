"""docs/mcap.md names every topic, schema and field the recorder writes (docs match code)."""

from canfdi.io.schemas import SCHEMAS
from tests.conftest import REPO


def test_every_topic_schema_and_field_is_documented():
    text = (REPO / "docs" / "mcap.md").read_text()
    for topic, (name, schema) in SCHEMAS.items():
        assert f"`{topic}`" in text and f"`{name}`" in text, topic
        for field in schema["properties"]:
            assert f"`{field}`" in text, (topic, field)
