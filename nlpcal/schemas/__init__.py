"""The JSON Schema of every document nlpcal writes, shipped with the package.

One schema per document kind, named by the kind's "format" (`SCHEMAS`); definitions the kinds
share (the nine parameters, a Table 1 row, the solver report, the verdict, the provenance) live
in `common.json`. A schema accepts the format versions nlpcal reads (`format_version` 1, written
before 0.2.0, and 2); keys are required where every version has them, numbers finite, and a
document is closed (no keys the schema does not name) wherever nlpcal writes all of its keys.

`validate(document)` checks a document against the schema of its kind; it needs the
`jsonschema` package (the `test` extra), which nlpcal itself does not.
"""

from __future__ import annotations

import json
from functools import cache
from importlib import resources

#: "format" of a document -> its schema file.
SCHEMAS = {
    "nlpcal-calibration": "calibration.json",
    "nlpcal-temperature-calibration": "temperature.json",
    "nlpcal-drift": "drift.json",
    "nlpcal-compass": "compass.json",
    "nlpcal-orthogonality-inversion": "inversion.json",
    "nlpcal-orthogonality-repeatability": "repeatability.json",
    "nlpcal-orthogonality-worst-case": "worst-case.json",
    "nlpcal-comparison": "comparison.json",
    "nlpcal-affine-correction": "affine-correction.json",
    "nlpcal-batch": "batch.json",
    "nlpcal-reproduction": "reproduction.json",
    "nlpcal-platform": "platform.json",
}
#: The schema of a row of a batch summary (DIR/summary.csv, empty cells read as "").
BATCH_SUMMARY_ROW = "batch-summary-row.json"
#: Where the schemas' "$id"s point: each file is found by its name after this.
BASE_URI = "https://example.org/nlpcal-schemas/"


@cache
def schema(name: str) -> dict:
    """The schema in file `name` (a value of SCHEMAS, "common.json" or BATCH_SUMMARY_ROW)."""
    return json.loads(resources.files(__name__).joinpath(name).read_text())


def schema_for(document: dict) -> dict:
    """The schema of a document's kind (its "format"); KeyError for a document without one."""
    return schema(SCHEMAS[document["format"]])


@cache
def validator(name: str):
    """A jsonschema validator of the schema in file `name`, its references resolved among the
    shipped schemas."""
    from jsonschema import Draft202012Validator
    from referencing import Registry, Resource

    def retrieve(uri: str):
        return Resource.from_contents(schema(uri.removeprefix(BASE_URI)))

    registry = Registry(retrieve=retrieve)  # type: ignore[call-arg]
    return Draft202012Validator(schema(name), registry=registry)


def validate(document: dict, name: str | None = None) -> None:
    """Raise jsonschema's ValidationError when `document` breaks the schema of its kind (or the
    schema in file `name`), or holds a number that is not finite (which JSON Schema cannot
    say: NaN compares false with every bound)."""
    from jsonschema import ValidationError

    validator(name or SCHEMAS[document["format"]]).validate(document)
    try:
        json.dumps(document, allow_nan=False)
    except ValueError:
        raise ValidationError("the document holds a number that is not finite") from None
