"""The results row: one evaluation of one method in one direction, as ``results.json`` holds it.

`ResultRow` is the schema of a row and its validation: every field typed, proportions
inside [0, 1], counts whole, numbers finite (null only where a field allows it), no field
it does not know. A row keeps which fields it was given: `ResultRow.dump` leaves out the
ones it was not (``sequence``, ``fusion``, ``query_dropout``, the fixed-``delta`` scores, and
whatever a row of an older run lacks), in the order of the fields here, so that
``json.dumps([row.dump() for row in rows], indent=2)`` is the bytes ``results.json`` has.
`parse_row` turns what a file holds into a row or one line naming the field at fault.
"""

from __future__ import annotations

import math
import typing
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Annotated, Any

import pydantic
from pydantic_core import PydanticCustomError

from vitaplace.engine.base.errors import UserError

__all__ = ["Difficulty", "FusionChoice", "QueryDropoutShares", "ResultRow", "RowError", "SequenceMatching",
           "parse_row"]


class RowError(UserError):
    """Something that is not a results row; the message names where it was and the field."""


def _problem(expected: str) -> PydanticCustomError:
    return PydanticCustomError("row", "expected {expected}", {"expected": expected})


@dataclass(frozen=True)
class _Number:
    """A number check: finite (or null when ``nullable``), whole when ``whole``, inside
    [``low``, ``high``]; ``what`` says what is expected when the generic wording would not."""

    low: float = -math.inf
    high: float = math.inf
    nullable: bool = False
    whole: bool = False
    what: str = ""

    @property
    def expected(self) -> str:
        return self.what or "a finite number" + (" or null" if self.nullable else "")

    def __call__(self, value: Any) -> Any:
        if value is None and self.nullable:
            return value
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise _problem(self.expected)
        if self.whole and value != int(value):
            raise _problem(self.expected)
        if not self.low <= value <= self.high:
            raise _problem(self.what or f"a number in [{self.low:g}, {self.high:g}]")
        return value


@dataclass(frozen=True)
class _Name:
    """Non-empty text (or null when ``nullable``)."""

    expected: str = "a non-empty name"
    nullable: bool = False

    def __call__(self, value: Any) -> Any:
        if value is None and self.nullable:
            return value
        if not isinstance(value, str) or not value:
            raise _problem(self.expected)
        return value


def _recall_keys(value: Any) -> Any:
    """``recall_at_k``: null or a mapping whose keys are whole K >= 1 written as text."""
    if value is not None and not (isinstance(value, Mapping) and all(isinstance(k, str) and k.isdecimal()
                                                                       and int(k) >= 1 for k in value)):
        raise _problem(_recall_keys.expected)  # type: ignore[attr-defined]
    return value


_recall_keys.expected = "a mapping from K (1, 5, ...) to a recall, or null"  # type: ignore[attr-defined]

# The field types: each checked by one of the checks above before pydantic converts it; the
# ``OrNull`` ones (and every field with a default) also take null.
Name = Annotated[str, pydantic.BeforeValidator(_Name())]
Real = Annotated[float, pydantic.BeforeValidator(_Number())]
RealOrNull = Annotated[float | None, pydantic.BeforeValidator(_Number(nullable=True))]
NonNegative = Annotated[float, pydantic.BeforeValidator(_Number(0))]
DistanceOrNull = Annotated[float | None, pydantic.BeforeValidator(_Number(0, nullable=True))]
Unit = Annotated[float, pydantic.BeforeValidator(_Number(0, 1))]
UnitOrNull = Annotated[float | None, pydantic.BeforeValidator(_Number(0, 1, nullable=True))]
Count = Annotated[int, pydantic.BeforeValidator(_Number(0, whole=True, what="a whole number (>= 0)"))]
CountOrNull = Annotated[int | None, pydantic.BeforeValidator(_Number(0, nullable=True, whole=True,
                                                                     what="a whole number (>= 0) or null"))]
#: a count that a tie may split (the expected count under the tie rule): whole unless one did
ExpectedCountOrNull = Annotated[int | float | None, pydantic.BeforeValidator(
    _Number(0, nullable=True, what="a count (>= 0; fractional where a tie splits it) or null"))]
Positive = Annotated[int, pydantic.BeforeValidator(_Number(1, whole=True, what="a whole number (>= 1)"))]


class _Part(pydantic.BaseModel):
    model_config = pydantic.ConfigDict(extra="forbid", validate_assignment=True)

    def dump(self) -> dict[str, Any]:
        """The fields it was given, in field order."""
        return self.model_dump(exclude_unset=True)


class Difficulty(_Part):
    """How hard the evaluation pair is, whatever the method (`vitaplace.engine.evaluation.difficulty`);
    null where a measure has nothing to measure, absent in the rows of runs older than it."""

    nearest_ref_median_m: DistanceOrNull = None
    nearest_ref_p90_m: DistanceOrNull = None
    nearest_ref_heading_median_deg: DistanceOrNull = None
    chance_r1: UnitOrNull = None
    query_touch_share: UnitOrNull = None
    reference_touch_share: UnitOrNull = None
    query_longest_stay_share: UnitOrNull = None
    reference_longest_stay_share: UnitOrNull = None
    touch_both_share: UnitOrNull = None
    touch_one_side_share: UnitOrNull = None
    touch_correspondence: UnitOrNull = None


class SequenceMatching(_Part):
    """The sequence matching settings the row was scored with (``metres``: over that much
    travelled distance), and the reference drive its local contrast window covers (median
    metres, ``window_span_m``)."""

    length: Positive
    velocity_steps: Positive
    window: Positive
    velocity_min: Real
    velocity_max: Real
    window_span_m: DistanceOrNull = None
    metres: DistanceOrNull = None


class FusionChoice(_Part):
    """A fusion's chosen weight, the two methods' spreads it divides by, and the selection
    evaluation's max F1 at that weight."""

    weight: NonNegative
    sigma_vision: Real
    sigma_touch: Real
    selection_max_f1: Unit


class QueryDropoutShares(_Part):
    """The shares of the query samples that lacked each sensor, as drawn."""

    camera: Unit
    whiskers: Unit


class ResultRow(_Part):
    """One results row (`vitaplace.engine.evaluation.evaluate.evaluate`'s summary of an
    evaluation pair, with what the pipeline adds). Required: the identity, ``n_queries`` (it
    sizes the block bootstrap's segments), ``n_revisit``, ``tau``, ``max_f1`` and ``auc``;
    every other field may be absent (a fixed ``delta``'s scores only with one; ``sequence``
    with sequence matching; ``fusion`` in a fusion's rows; ``query_dropout`` in a drop-out
    evaluation's rows; the rest in rows of runs older than the field)."""

    environment: Name
    method: Name
    direction: Name
    n_queries: Annotated[int, pydantic.BeforeValidator(_Number(1, whole=True, what="a whole number of queries (>= 1)"))]
    n_references: CountOrNull = None
    n_revisit: Count
    tau: NonNegative
    max_f1: Unit
    precision_at_max_f1: UnitOrNull = None
    recall_at_max_f1: UnitOrNull = None
    delta_at_max_f1: RealOrNull = None  #: null: the best was to accept nothing
    auc: Unit
    auc_method: Annotated[str | None, pydantic.BeforeValidator(_Name("text naming how AUC was computed", True))] = None
    recall_at_100_precision: UnitOrNull = None
    recall_at_k: Annotated[dict[str, Unit] | None, pydantic.BeforeValidator(_recall_keys)] = None
    tied_share: UnitOrNull = None  #: the share of queries whose best match is tied (the tie rule decided them)
    delta: RealOrNull = None  #: the fixed ``scoring.delta`` and the scores there, when one is set
    precision: UnitOrNull = None
    recall: UnitOrNull = None
    f1: UnitOrNull = None
    tp: ExpectedCountOrNull = None
    fp: ExpectedCountOrNull = None
    fn: ExpectedCountOrNull = None
    tn: CountOrNull = None
    n_accepted: CountOrNull = None
    heading_tolerance_deg: DistanceOrNull = None  #: null: position only
    sequence: SequenceMatching | None = None
    difficulty: Difficulty | None = None
    fusion: FusionChoice | None = None
    query_dropout: QueryDropoutShares | None = None
    #: null: no training world's threshold to apply (no such evaluation, or no revisit in it)
    f1_at_e1_threshold: UnitOrNull = None
    e1_threshold: RealOrNull = None


def _expected(loc: tuple[int | str, ...]) -> str:
    """What the field at ``loc`` (a path through `ResultRow` and its parts) expects."""
    model: Any = ResultRow
    check: Any = None
    for part in loc:
        field = model.model_fields[part]
        check = next((m.func for m in field.metadata if isinstance(m, pydantic.BeforeValidator)), None)
        model = next((t for t in (field.annotation, *typing.get_args(field.annotation))
                      if isinstance(t, type) and issubclass(t, _Part)), None)
    return check.expected if check is not None else "a mapping"


#: what a row's field expects when pydantic's own check fails (not one of the checks above)
_PYDANTIC_EXPECTED = {"model_type": "a mapping", "dict_type": "a mapping", "int_from_float": "a whole number",
                      "extra_forbidden": "no such field (not one of a results row's)"}


def _line(error: Mapping[str, Any]) -> str:
    name = ".".join(str(part) for part in error["loc"])
    if error["type"] == "missing":
        return f"field {name!r} is None, expected {_expected(tuple(error['loc']))}"
    value = error["input"]
    expected = (error["ctx"]["expected"] if error["type"] == "row"
                else _PYDANTIC_EXPECTED.get(error["type"], error["msg"]))
    return f"field {name!r} is {value!r:.60}, expected {expected}"


def parse_row(data: Any, where: str, error: type[UserError] = RowError) -> ResultRow:
    """``data`` (a mapping read from ``results.json``, or a row) as a `ResultRow`; else
    ``error``, one line: ``where``, the first field at fault, its value and what it expects."""
    if isinstance(data, ResultRow):
        return data
    if not isinstance(data, Mapping):
        raise error(f"{where}: a {type(data).__name__}, expected a result row (a JSON object)")
    try:
        return ResultRow.model_validate(data)
    except pydantic.ValidationError as exc:
        raise error(f"{where}: {_line(exc.errors()[0])}") from None

