"""One versioned document base for every result nlpcal writes and reads back.

Every result type is a dataclass that derives from `Document` and names its kind once:

    FORMAT = "nlpcal-calibration"     the discriminator written as "format"
    FORMAT_VERSION = 2                written as "format_version" (READS_VERSIONS are read)

and implements `body()` (the document without the envelope) and `from_body(reader)`; a kind
with a notion of quality also has a `verdict` property (`nlpcal.verdict`), written right after the
envelope as "verdict" and recomputed, never read, when the document is loaded. The base
gives every kind the same verbs: `to_dict`, `to_json`, `save`, and `from_dict`, `from_json`,
`load`. Reading goes through a `DocumentReader`, which checks each field's type, shape, finiteness
and range and turns any malformed document into an `InputError` that names the file and the
field, so a document read from disk is validated as strictly as a CSV.

Documents written by nlpcal 0.1.0 had no "format" key; `load_any` recognises them by their keys.
The JSON Schema of every kind ships in `nlpcal.schemas`.
"""

from __future__ import annotations

import json
from collections.abc import Iterator, Mapping, MutableMapping
from dataclasses import dataclass, field, fields
from functools import cache, partial
from pathlib import Path
from typing import Any, ClassVar, TypeVar

import numpy as np

from . import validation
from .errors import InputError
from .io.files import existing_file, json_text, write_json_atomic
from .io.strict import strict
from .verdict import Verdict
from .version import __version__

#: Deepest nesting accepted in a document (deeper JSON is refused before it is walked).
MAX_DEPTH = 32
_MISSING: Any = object()


class DocumentReader:
    """Typed access to the fields of a JSON document, with one error style.

    `source` names the document in messages ("params.json", "the drift file").
    """

    def __init__(self, document, source: str = "document", path: str = ""):
        if not isinstance(document, dict):
            raise InputError(f"{source}: expected a JSON object, got {type(document).__name__}")
        self.document = document
        self.source = source
        self.path = path

    def _where(self, key) -> str:
        return f"{self.source}: {self.path}{key}"

    def has(self, key) -> bool:
        return self.document.get(key) is not None

    def raw(self, key, default=_MISSING):
        if key not in self.document or self.document[key] is None:
            if default is _MISSING:
                raise InputError(f"{self.source}: missing {self.path}{key}")
            return default
        return self.document[key]

    def number(self, key, default=_MISSING, *, positive: bool = False, minimum=None, maximum=None):
        value = self.raw(key, default)
        if value is default and default is not _MISSING:
            return default
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise InputError(f"{self._where(key)} must be a number, got {value!r:.40}")
        return validation.number(
            value, self._where(key), positive=positive, minimum=minimum, maximum=maximum
        )

    def integer(self, key, default=_MISSING, *, minimum: int = 0):
        value = self.raw(key, default)
        if value is default and default is not _MISSING:
            return default
        if isinstance(value, bool) or not isinstance(value, int) or value < minimum:
            raise InputError(
                f"{self._where(key)} must be an integer of at least {minimum}, got {value!r:.40}"
            )
        return value

    def string(self, key, default=_MISSING, *, options=None):
        value = self.raw(key, default)
        if value is default and default is not _MISSING:
            return default
        if not isinstance(value, str):
            raise InputError(f"{self._where(key)} must be a string, got {value!r:.40}")
        if options is not None and value not in options:
            raise InputError(
                f"{self._where(key)} must be one of {', '.join(options)}, got {value!r:.40}"
            )
        return value

    def array(self, key, shape, default=_MISSING) -> np.ndarray:
        """A finite float array of `shape` (a list of numbers, or a list of such lists)."""
        value = self.raw(key, default)
        if value is default and default is not _MISSING:
            return default
        if not _numeric_nest(value):
            raise InputError(f"{self._where(key)} must be numbers of shape {shape}")
        try:
            array = np.asarray(value, dtype=float)
        except (ValueError, OverflowError):  # ragged lists, integers beyond a double
            raise InputError(f"{self._where(key)} must be numbers of shape {shape}") from None
        if array.shape != tuple(shape):
            raise InputError(
                f"{self._where(key)} must have shape {tuple(shape)}, got {array.shape}"
            )
        if not np.isfinite(array).all():
            raise InputError(f"{self._where(key)} contains non-finite values")
        return array

    def mapping(self, key, default=_MISSING):
        value = self.raw(key, default)
        if value is default and default is not _MISSING:
            return default
        if not isinstance(value, dict):
            raise InputError(f"{self._where(key)} must be a JSON object")
        return value

    def items(self, key, default=_MISSING) -> list:
        value = self.raw(key, default)
        if value is default and default is not _MISSING:
            return default
        if not isinstance(value, list):
            raise InputError(f"{self._where(key)} must be a list")
        return value

    def strings(self, key, default=_MISSING) -> list:
        value = self.items(key, default)
        if value is default and default is not _MISSING:
            return default
        if not all(isinstance(v, str) for v in value):
            raise InputError(f"{self._where(key)} must be a list of strings")
        return list(value)

    def provenance(self, key: str = "input", *, strings=(), lists=(), units=()) -> dict:
        """The provenance block of a document ("input"): what nlpcal uses of it checked (the
        `strings` keys strings, the `lists` keys lists of strings, the `units` keys among the
        units given), the rest kept as it is."""
        block = self.reader(key, None)
        if block is None:
            return {}
        for name in strings:
            block.string(name, None)
        for name in lists:
            block.strings(name, None)
        for name, options in units:
            block.string(name, None, options=list(options))
        return dict(block.document)

    def reader(self, key, default=_MISSING):
        """A reader of the object at `key` (messages name the path to it); `default` when the
        key is missing or null and a default is given."""
        value = self.mapping(key, default)
        if value is default and default is not _MISSING:
            return default
        return DocumentReader(value, self.source, f"{self.path}{key}.")


def _numeric_nest(value) -> bool:
    if isinstance(value, list):
        return all(_numeric_nest(v) for v in value)
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def _depth(value, limit: int = MAX_DEPTH) -> int:
    """Nesting depth of a parsed JSON value, stopping at `limit`."""
    stack, deepest = [(value, 1)], 1
    while stack:
        item, level = stack.pop()
        deepest = max(deepest, level)
        if deepest > limit:
            return deepest
        children = (
            item.values() if isinstance(item, dict) else item if isinstance(item, list) else ()
        )
        stack.extend((child, level + 1) for child in children)
    return deepest


class Document:
    """Base of every result nlpcal serialises (dataclasses that set FORMAT and FORMAT_VERSION)."""

    FORMAT: ClassVar[str] = ""
    #: The version written. A release bumps it once per kind whose document changed (not once
    #: per change); 2 is that of nlpcal 0.2.0 (the solver report, the verdict, the unit's
    #: source, the model and the other keys added since 0.1.0).
    FORMAT_VERSION: ClassVar[int] = 2
    #: The versions still read (1: written before 0.2.0; a document without "format_version",
    #: from nlpcal 0.1.0, counts as 1).
    READS_VERSIONS: ClassVar[tuple] = (1, 2)
    #: Earlier discriminators still read: (key, value) pairs that identify the same kind.
    LEGACY_FORMATS: ClassVar[tuple] = ()
    #: What the kind is called in messages.
    WHAT: ClassVar[str] = "nlpcal document"

    def body(self) -> dict:
        raise NotImplementedError

    @property
    def verdict(self) -> Verdict | None:
        """What the result is worth (`nlpcal.verdict.judge` of its quality fields), or None for
        a kind without a notion of quality."""
        return None

    @classmethod
    def from_body(cls, reader: DocumentReader):
        raise NotImplementedError

    # -- writing -----------------------------------------------------------------------------

    def to_dict(self) -> dict:
        """The document: "format", "format_version", "verdict" (kinds with one), the body and
        "nlpcal_version"."""
        body = self.body()
        verdict = self.verdict
        document = {
            "format": self.FORMAT,
            "format_version": self.FORMAT_VERSION,
            **({} if verdict is None else {"verdict": verdict.to_dict()}),
            **body,
            "nlpcal_version": body.get("nlpcal_version", __version__),
        }
        return strict(document, f"the {self.WHAT}")

    def to_json(self) -> str:
        """Strict JSON of the document (`to_dict`: finite numbers, no null)."""
        return json_text(self.to_dict())

    def save(self, path) -> None:
        """Write the document to `path` atomically."""
        write_json_atomic(path, self.to_dict())

    # -- reading -----------------------------------------------------------------------------

    @classmethod
    def accepts(cls, document: dict) -> bool:
        """Whether `document` is of this kind (its "format", or a legacy marker)."""
        if document.get("format") == cls.FORMAT:
            return True
        return "format" not in document and any(
            document.get(key) == value if value is not None else key in document
            for key, value in cls.LEGACY_FORMATS
        )

    @classmethod
    def from_dict(cls, document, source: str = ""):
        """The result stored in `document`; InputError when it is not a valid one of this kind."""
        source = source or cls.WHAT
        if not isinstance(document, dict):
            raise InputError(f"{source}: not an {cls.WHAT} (expected a JSON object)")
        if _depth(document) > MAX_DEPTH:
            raise InputError(f"{source}: nested deeper than {MAX_DEPTH} levels; not an {cls.WHAT}")
        if not cls.accepts(document):
            found = document.get("format")
            raise InputError(
                f"{source}: not an {cls.WHAT} (format {found!r}; expected {cls.FORMAT!r})"
            )
        version = document.get("format_version", 1)
        if isinstance(version, bool) or version not in cls.READS_VERSIONS:
            raise InputError(
                f"{source}: format_version {version!r}; this nlpcal reads format_version "
                f"{' and '.join(map(str, cls.READS_VERSIONS))} of {cls.WHAT}s"
            )
        return cls.from_body(DocumentReader(document, source))

    @classmethod
    def from_json(cls, text: str, source: str = ""):
        try:
            document = parse_json(text, source or cls.WHAT)
        except RecursionError:
            raise InputError(f"{source or cls.WHAT}: nested too deeply; not valid JSON") from None
        return cls.from_dict(document, source)

    @classmethod
    def load(cls, path):
        """Read and validate the document at `path`."""
        return cls.from_dict(read_json_document(path, cls.WHAT), str(path))


RecordT = TypeVar("RecordT", bound="Record")


@cache
def _field_names(kind: type) -> tuple:
    return tuple(f.name for f in fields(kind) if f.name != "extra")


class Record(MutableMapping):
    """Base of the typed records inside documents (a Table 1 row, the identifiability block,
    the provenance): dataclasses whose fields are the keys of the JSON object they write,
    spelled once, with a last field `extra` that keeps, in order, the keys of no field (the
    entries other documents add, keys of a later version).

    A field that is None is absent from `to_dict`, from iteration and from `key in record`, as
    a document holds no null; `record[key]` gives it as None, as the objects in memory held it,
    and `record.get(key, default)` the default. A record also reads and writes as that object
    (`record["std"]`, `record.get("coverage")`, `dict(record)`, `record.update(...)`), so code
    written against the document keeps working; the library reads the fields. Records compare
    equal to each other and to dicts by their entries.
    """

    extra: dict
    #: The order of the keys of the object a record was read from (`from_dict`), which
    #: `to_dict` keeps; keys set later follow it, in the order of the fields.
    _order: tuple = ()

    @classmethod
    def keys_of(cls) -> tuple:
        """The document keys of the fields, in order."""
        return _field_names(cls)

    def to_dict(self) -> dict:
        """The JSON object: the fields that are not None, in order, then `extra`; a record read
        by `from_dict` keeps the order of the object it was read from."""
        values = {name: getattr(self, name) for name in self.keys_of()}
        entries = {**{k: v for k, v in values.items() if v is not None}, **self.extra}
        if not self._order:
            return entries
        return {**{k: entries[k] for k in self._order if k in entries}, **entries}

    @classmethod
    def from_dict(cls: type[RecordT], document: Mapping) -> RecordT:
        """The record of a JSON object: its keys of a field as those fields, the rest `extra`."""
        names = set(cls.keys_of())
        known = {k: v for k, v in document.items() if k in names}
        extra = {k: v for k, v in document.items() if k not in names}
        record = cls(**known, extra=extra)  # type: ignore[call-arg]
        record._order = tuple(document)
        return record

    @classmethod
    def of(cls: type[RecordT], value: Mapping) -> RecordT:
        """`value` if it is a record of this kind, else the record of the mapping."""
        return value if isinstance(value, cls) else cls.from_dict(value)

    def __getitem__(self, key):
        if key in self.keys_of():
            return getattr(self, key)
        return self.extra[key]

    def __contains__(self, key) -> bool:
        return key in self.extra or (key in self.keys_of() and getattr(self, key) is not None)

    def get(self, key, default=None):
        if key not in self:  # absent, or a field that is None
            return default
        return self[key]

    def __setitem__(self, key, value) -> None:
        if key in self.keys_of():
            setattr(self, key, value)
        else:
            self.extra[key] = value

    def __delitem__(self, key) -> None:
        if key in self.keys_of() and getattr(self, key) is not None:
            setattr(self, key, None)
        else:
            del self.extra[key]

    def __iter__(self) -> Iterator:
        return iter(self.to_dict())

    def __len__(self) -> int:
        return len(self.to_dict())

    def __eq__(self, other) -> bool:
        if not isinstance(other, Mapping):
            return NotImplemented
        return self.to_dict() == dict(other.items())

    __hash__ = None  # type: ignore[assignment]

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self.to_dict()!r})"


@dataclass(eq=False, repr=False)
class TableRow(Record):
    """One row of Table 1 in [1]: the statistics of |B1| (or of the measured |B_M|) after a
    solve, and how the solve got there. Every field but `label` may be absent (None).

    Attributes
    ----------
    label : str
        What the row is: "measured", "cycle 3", "joint", "bias corrected", ...
    max, min, mean, std, range : float
        Of |B1| [unit]; std with ddof `nlpcal.statistics.STD_DDOF`. A row from the moments
        (`from_moments`) has no max, min and range.
    objective : float
        The objective: the variance of |B1|, or the mean square of |B1| - F. [unit^2]
    max_abs_u : float
        The largest |(|B1| / F)^2 - 1|, F the reference or the mean of |B1|. [1]
    residual_lag1_autocorrelation : float
        Of the residuals |B1| - F (or about the mean) in the order of the samples. [1]
    rmse : float
        The RMSE of |B1| against a reference series (Eq. 10 of Liu et al. 2022). [unit]
    robust_objective : float
        With a robust loss: the mean loss of the residuals. [unit^2]
    downweighted : int
        With a robust loss: the samples beyond its scale.
    weighted_centre : float
        With a robust loss: the weighted mean of |B1|. [unit]
    series_rel_error : float
        The relative gap between the moment objective and the exact one. [1]
    from_moments : bool
        True for a row computed from the moments alone.
    parameters : dict
        The nine parameters at the row (offsets [unit], scale errors [1], angles [deg]).
    iterations : int
        IPOPT's iterations of the solve.
    wall_s : float
        Its wall time. [s]
    extra : dict
        Keys other documents add (a comparison's "status", "variant", ...).

    References
    ----------
    [1] Zhou et al. (2010), see `nlpcal.models.zhou2010`.

    Examples
    --------
    >>> from nlpcal.results import TableRow
    >>> row = TableRow("cycle 1", mean=49462.0, std=16.4, iterations=12, wall_s=0.01)
    >>> row.std, row["std"], row.to_dict()["label"]
    (16.4, 16.4, 'cycle 1')
    """

    label: str
    max: float | None = None
    min: float | None = None
    mean: float | None = None
    std: float | None = None
    range: float | None = None
    objective: float | None = None
    max_abs_u: float | None = None
    residual_lag1_autocorrelation: float | None = None
    rmse: float | None = None
    robust_objective: float | None = None
    downweighted: int | None = None
    weighted_centre: float | None = None
    series_rel_error: float | None = None
    from_moments: bool | None = None
    parameters: dict | None = None
    iterations: int | None = None
    wall_s: float | None = None
    extra: dict = field(default_factory=dict)

    @classmethod
    def read(cls, row, source: str) -> TableRow:
        """A row of a document: its label a string, its statistics numbers, `parameters` an
        object (InputError naming `source` otherwise); keys of no field are kept."""
        reader = DocumentReader(row, source)
        for name in cls.keys_of():
            if name in ("label", "parameters", "from_moments"):
                continue
            reader.number(name, None)
        reader.string("label", "")
        reader.mapping("parameters", None)
        return cls.from_dict({"label": "", **row})


@dataclass(eq=False, repr=False)
class Provenance(Record):
    """Where a result's samples came from (the "input" block of a document): the log, its
    columns and unit, and how it was read (`nlpcal.io.Log.metadata`). A field that is None is
    absent from the document.

    Attributes
    ----------
    log : str
        The log's path, "-" for stdin.
    columns : list of str
        The field columns read.
    log_unit : str
        The unit of the field columns (after the plausibility check: "raw" for counts).
    unit_source : str
        Where that unit came from ("option", "names", "format" or "assumed").
    layout : dict
        The file's layout (delimiter, header, comment lines), to write a table back alike.
    csv_engine : str
        The reader that parsed a text log.
    rows_dropped : int
        Rows left out (`--drop-invalid`, readings of exactly zero).
    temperature_column : str
        The temperature column of a temperature calibration.
    extra : dict
        What else a document records (the turn column of a compass calibration, the rotation
        an imported correction does not carry, ...).

    Examples
    --------
    >>> from nlpcal.results import Provenance
    >>> Provenance(log="run.csv", columns=["mx", "my", "mz"], log_unit="uT").to_dict()
    {'log': 'run.csv', 'columns': ['mx', 'my', 'mz'], 'log_unit': 'uT'}
    """

    log: str | None = None
    columns: list[str] | None = None
    log_unit: str | None = None
    unit_source: str | None = None
    layout: dict | None = None
    csv_engine: str | None = None
    rows_dropped: int | None = None
    temperature_column: str | None = None
    extra: dict = field(default_factory=dict)


def distinct(pairs, source: str, what: str = "key") -> dict:
    """A dict of (name, value) pairs; InputError when a name comes twice with different values,
    since which one was meant cannot be known (the same value twice is kept once)."""
    found: dict = {}
    for name, value in pairs:
        if name in found and not _same(found[name], value):
            raise InputError(
                f"{source}: {what} {name!r} is given twice with different values; keep one"
            )
        found[name] = value
    return found


def _same(first, second) -> bool:
    if isinstance(first, np.ndarray) or isinstance(second, np.ndarray):
        return np.shape(first) == np.shape(second) and bool(np.all(first == second))
    return bool(first == second) and type(first) is type(second)


def parse_json(text: str, source: str, what: str = "JSON document"):
    """The parsed JSON of `text`; InputError naming `source` when it is not valid JSON or an
    object repeats a key with different values."""
    try:
        return json.loads(text, object_pairs_hook=partial(distinct, source=source))
    except json.JSONDecodeError as exc:
        raise InputError(f"{source}: not a valid {what} ({exc})") from None


def read_json_document(path, what: str = "JSON document"):
    """The parsed JSON of a file (`parse_json`), refusing files nested deeper than Python
    reads."""
    path = existing_file(path, f"a {what}")
    try:
        return parse_json(path.read_text(), str(path), what)
    except UnicodeDecodeError as exc:
        raise InputError(f"{path}: not a valid {what} ({exc})") from None
    except RecursionError:
        raise InputError(f"{path}: nested deeper than Python can read; not a {what}") from None


def load_any(path, kinds):
    """Read `path` as whichever of the Document classes `kinds` accepts it."""
    document = read_json_document(path, "nlpcal document")
    if isinstance(document, dict):
        for kind in kinds:
            if kind.accepts(document):
                return kind.from_dict(document, str(Path(path)))
    names = ", ".join(kind.WHAT for kind in kinds)
    raise InputError(f"{path}: not one of: {names}")
