"""The type of JSON data that has no shape of its own: a JSON Schema, a request body with a
caller's extra fields, a reply from a server that is checked field by field as it is read.

Data with a shape gets a model (pydantic on the wire and in files, a dataclass or TypedDict
inside); these are for the rest. Containers are read-only (`Sequence`, `Mapping`) inside a value
so that a `list[str]` or a `dict[str, int]` is a JSON value as it is.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import TypeAlias, Union

JsonValue: TypeAlias = Union[str, int, float, bool, None, Sequence["JsonValue"], Mapping[str, "JsonValue"]]
JsonObject: TypeAlias = dict[str, JsonValue]  # one JSON object (json.loads of an object, or one to json.dumps)

__all__ = ["JsonObject", "JsonValue"]
