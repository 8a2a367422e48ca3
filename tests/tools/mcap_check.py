"""Check a recording the way a viewer reads it: the reference ``mcap`` reader with CRCs
validated, every JSON channel's schema listing its fields (with units), every JSON message
valid against its schema, log times on the wall clock."""

from __future__ import annotations

import json
import time
from collections import Counter
from pathlib import Path
from typing import Any

import jsonschema
from mcap.reader import make_reader

#: Log times must be within this of the check (s): the wall clock, not the link's.
WALL_CLOCK_SLACK_S = 24 * 3600


def _described(schema: dict[str, Any], where: str) -> None:
    """Every field of an object schema has a type and a description (its unit)."""
    for name, field in schema.get("properties", {}).items():
        assert "description" in field or "properties" in field, f"{where}.{name}: no description"
        if field.get("type") == "object" or "properties" in field:
            _described(field, f"{where}.{name}")
        items = field.get("items")
        if isinstance(items, dict) and "properties" in items:
            _described(items, f"{where}.{name}[]")


def check_recording(path: Path) -> Counter[str]:
    """Read ``path`` with the reference reader (CRCs on) and check it; message count by
    topic."""
    counts: Counter[str] = Counter()
    validators: dict[int, jsonschema.protocols.Validator] = {}
    now_ns = time.time_ns()
    with path.open("rb") as stream:
        reader = make_reader(stream, validate_crcs=True)
        summary = reader.get_summary()
        assert summary is not None and summary.statistics is not None, "no summary section"
        for channel in summary.channels.values():
            if channel.message_encoding == "json":
                schema = summary.schemas[channel.schema_id]
                assert schema.encoding == "jsonschema", channel.topic
                body = json.loads(schema.data)
                assert body.get("properties"), f"{channel.topic}: the schema lists no fields"
                _described(body, channel.topic)
                jsonschema.Draft202012Validator.check_schema(body)
                validators[channel.id] = jsonschema.Draft202012Validator(body)
        for _schema, channel, message in reader.iter_messages():
            counts[channel.topic] += 1
            assert abs(message.log_time - now_ns) < WALL_CLOCK_SLACK_S * 1e9, (
                f"{channel.topic}: log time {message.log_time} ns is not the wall clock")
            if channel.id in validators:
                validators[channel.id].validate(json.loads(message.data))
        assert sum(counts.values()) == summary.statistics.message_count
    return counts
