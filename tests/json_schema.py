"""A JSON Schema checker for the keywords docs/json-schema.json uses, with the standard library alone.

It refuses a schema with any other keyword, so the schema cannot grow a rule this checker ignores.
`validate(instance, schema)` returns the list of problems, each with the path to the value.
"""

from __future__ import annotations

from typing import Any

ANNOTATIONS = {"$schema", "$id", "title", "description", "$defs"}
KEYWORDS = {"type", "const", "enum", "required", "properties", "additionalProperties", "items", "minItems", "minimum",
            "oneOf", "$ref"}
TYPES = {
    "object": lambda x: isinstance(x, dict),
    "array": lambda x: isinstance(x, list),
    "string": lambda x: isinstance(x, str),
    "boolean": lambda x: isinstance(x, bool),
    "null": lambda x: x is None,
    "integer": lambda x: isinstance(x, int) and not isinstance(x, bool),
    "number": lambda x: isinstance(x, (int, float)) and not isinstance(x, bool),
}


def validate(instance: Any, schema: dict, root: dict | None = None, where: str = "$") -> list[str]:
    root = root or schema
    unknown = set(schema) - KEYWORDS - ANNOTATIONS
    if unknown:
        raise ValueError(f"{where}: schema keyword(s) {sorted(unknown)} not supported by this checker")
    problems: list[str] = []
    if "$ref" in schema:
        ref = schema["$ref"]
        assert ref.startswith("#/$defs/"), ref
        problems += validate(instance, root["$defs"][ref.removeprefix("#/$defs/")], root, where)
    if "type" in schema:
        kinds = schema["type"] if isinstance(schema["type"], list) else [schema["type"]]
        if not any(TYPES[k](instance) for k in kinds):
            return problems + [f"{where}: {instance!r:.60} is not of type {kinds}"]
    if "const" in schema and instance != schema["const"]:
        problems.append(f"{where}: {instance!r} is not {schema['const']!r}")
    if "enum" in schema and instance not in schema["enum"]:
        problems.append(f"{where}: {instance!r} is not one of {schema['enum']}")
    if "minimum" in schema and TYPES["number"](instance) and instance < schema["minimum"]:
        problems.append(f"{where}: {instance} < {schema['minimum']}")
    if "oneOf" in schema:
        passing = [s for s in schema["oneOf"] if not validate(instance, s, root, where)]
        if len(passing) != 1:
            problems.append(f"{where}: matches {len(passing)} of the oneOf schemas, not exactly one")
    if isinstance(instance, dict):
        for key in schema.get("required", []):
            if key not in instance:
                problems.append(f"{where}: lacks {key!r}")
        props = schema.get("properties", {})
        extra = schema.get("additionalProperties", True)
        for key, value in instance.items():
            if key in props:
                problems += validate(value, props[key], root, f"{where}.{key}")
            elif extra is False:
                problems.append(f"{where}: unexpected key {key!r}")
            elif isinstance(extra, dict):
                problems += validate(value, extra, root, f"{where}.{key}")
    if isinstance(instance, list):
        if len(instance) < schema.get("minItems", 0):
            problems.append(f"{where}: fewer than {schema['minItems']} items")
        if "items" in schema:
            for i, item in enumerate(instance):
                problems += validate(item, schema["items"], root, f"{where}[{i}]")
    return problems
