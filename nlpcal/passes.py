"""A pass over the samples, block by block, for numpy arrays, memory maps and Dask arrays.

Every statistic nlpcal takes from a log (the Gram matrix of `nlpcal.moments`, the Table 1 rows of
`nlpcal.statistics`, the weighted sums of a robust loss) is a sum over the samples, so it is
gathered block by block and the partial results are merged in order. `reduce` is that pass. In
memory (an array or a memory map) the blocks are contiguous shares of the rows, one per thread
(`nlpcal.chunks.map_shares`). For a Dask array the blocks are its chunks: one task per chunk on
the current Dask scheduler, the partial results merged by a tree of tasks in the order of the
rows, so that one result reaches the caller and a pass takes O(block) memory per worker.

The same work function runs on both: it receives a block of raw rows and the block of the
reference (None, a number or an array of the block's rows) and loops over chunks of its own, so
a sum over a Dask array differs from the in-memory one only by the order of additions.

A Dask array enters the library as `LazySamples`. Its survey gathers what the rest of a
calibration reads without a pass of its own: the range and the sum of every column, the first
rows, and the evenly strided subsamples `values[::max(1, N // m)]` for the sizes m of
`SURVEY_SIZES` (the sphere frame, the attitude coverage, the median absolute deviation of the
residuals, the mean magnitude). It is not a pass of its own: the first pass over a log not yet
surveyed (`reduce`, whatever its work) gathers it along, block by block (`Surveying`), and so
do the reader's checks that wait for that pass (`Pending`). Only a step that asks for the
survey before any pass (`LazySamples.survey`) runs it alone. The first rows come from the first
block without a pass. Indexing rows returns numpy arrays, from the survey when it has them;
turning the whole array into numpy is refused, so that no step loads a log larger than memory
by accident.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from . import chunks

#: Sizes of the strided subsamples the survey of a Dask log gathers: the sphere frame and the
#: attitude coverage (20 000), the median absolute deviation of the residuals (50 000), the mean
#: magnitude (100 000).
SURVEY_SIZES = (20_000, 50_000, 100_000)
#: Leading rows the survey keeps (the shift of the sums of `nlpcal.statistics.MagnitudeStats`).
SURVEY_HEAD = 1024


def is_dask(value) -> bool:
    """Whether `value` is a Dask collection (an array or a DataFrame)."""
    if "dask" not in sys.modules:  # nothing made with Dask exists before Dask is imported
        return False
    import dask

    return bool(dask.is_dask_collection(value))


def column_ranges(block) -> tuple:
    """Per-column minimum and maximum of a block of rows, NaN where a column has a NaN. One
    column at a time: a strided 1-d reduction is an order of magnitude faster than numpy's
    reduction along the first axis of an (N, 3) array."""
    block = np.asarray(block, dtype=float)
    columns = block.reshape(block.shape[0], -1)
    low, high = np.full(columns.shape[1], np.inf), np.full(columns.shape[1], -np.inf)
    if columns.shape[0]:
        for k in range(columns.shape[1]):  # NaN propagates through min and max
            low[k], high[k] = columns[:, k].min(), columns[:, k].max()
    return low, high


@dataclass
class Survey:
    """What one pass gathers of a Dask log: per column its lowest and highest value, how many
    values are <= 0, their sum and the sum of their squares.

    rows : step -> the rows values[::step]; head : the first SURVEY_HEAD rows.
    """

    low: np.ndarray
    high: np.ndarray
    nonpositive: np.ndarray
    total: np.ndarray
    squares: np.ndarray
    head: np.ndarray
    rows: dict = field(default_factory=dict)

    def columns(self, selection) -> Survey:
        """The survey of some columns: a slice, or one column index (whose rows are (N,))."""
        pick = [selection] if isinstance(selection, int) else selection
        return Survey(
            self.low[pick],
            self.high[pick],
            self.nonpositive[pick],
            self.total[pick],
            self.squares[pick],
            self.head[:, selection],
            {step: rows[:, selection] for step, rows in self.rows.items()},
        )

    def scaled(self, factor: float) -> Survey:
        """The survey of the values times a positive factor."""
        return Survey(
            self.low * factor,
            self.high * factor,
            self.nonpositive,
            self.total * factor,
            self.squares * factor**2,
            self.head * factor,
            {step: rows * factor for step, rows in self.rows.items()},
        )


def survey_block(block, start: int, steps: tuple) -> Survey:
    """The survey of the rows start:start + len(block) of a log."""
    block = np.asarray(block, dtype=float)
    low, high = column_ranges(block)
    flat = block.reshape(block.shape[0], -1)
    return Survey(
        low=low,
        high=high,
        nonpositive=(flat <= 0).sum(axis=0),
        total=flat.sum(axis=0),
        squares=np.einsum("ij,ij->j", flat, flat),
        head=block[: max(0, SURVEY_HEAD - start)],
        rows={step: block[(-start) % step :: step] for step in steps},
    )


def merge_surveys(first: Survey, second: Survey) -> Survey:
    """Two surveys of neighbouring rows, `second` after `first`."""
    return Survey(
        low=np.minimum(first.low, second.low),  # NaN propagates
        high=np.maximum(first.high, second.high),
        nonpositive=first.nonpositive + second.nonpositive,
        total=first.total + second.total,
        squares=first.squares + second.squares,
        head=np.concatenate([first.head, second.head])[:SURVEY_HEAD],
        rows={step: np.concatenate([first.rows[step], second.rows[step]]) for step in first.rows},
    )


def merge_optional(first: Survey | None, second: Survey | None) -> Survey | None:
    """`merge_surveys` of two neighbouring surveys, None when there are none."""
    return None if first is None or second is None else merge_surveys(first, second)


def merge_all(surveys: list) -> Survey:
    """The surveys of consecutive blocks, in order, merged at once."""
    return Survey(
        low=np.min([s.low for s in surveys], axis=0),  # NaN propagates
        high=np.max([s.high for s in surveys], axis=0),
        nonpositive=np.sum([s.nonpositive for s in surveys], axis=0),
        total=np.sum([s.total for s in surveys], axis=0),
        squares=np.sum([s.squares for s in surveys], axis=0),
        head=np.concatenate([s.head for s in surveys])[:SURVEY_HEAD],
        rows={step: np.concatenate([s.rows[step] for s in surveys]) for step in surveys[0].rows},
    )


@dataclass
class Ledger:
    """The passes over one log's data and what each cost, shared by the arrays made from it
    (its columns, its values in another unit).

    passes : how many passes over the data have run.
    timings : (what, seconds) of every pass: "read" and "count" (a reader's, the rows of
        blocks of unknown length counted), "survey", or the name of the work of the pass
        ("MomentBlock", "StatisticsBlock" ...; "+ survey" when the survey came along); and of
        the reads of the first block ("head", not a pass). [s]
    """

    passes: int = 0
    timings: list = field(default_factory=list)

    def record(self, what: str, seconds: float, whole: bool = True) -> None:
        """Count a pass (`whole`) or a read of a few blocks, and what it cost. [s]"""
        self.passes += int(whole)
        self.timings.append((what, seconds))


@dataclass
class Pending:
    """Checks of a reader that wait for the first pass over a log (`nlpcal.io.lazy`): `parts`
    are Dask objects computed along with that pass (reading the same blocks, so each is read
    once), and `settle(values)` takes their values. It returns True when the pass stands, or
    False when it found that the blocks are not as declared: then it has rebuilt the arrays
    and the pass runs again (a pass more, counted)."""

    parts: list
    settle: Callable


def _whole_rows(array):
    """A Dask array of rows in one chunk across its columns."""
    return array.rechunk({1: -1}) if array.ndim == 2 else array


class LazySamples:
    """Rows of a Dask array that stay where they are: samples (N, 3) or a reference series (N,).

    array : the Dask array, in one chunk across its columns.
    survey : its survey when already gathered (by a reader's pass), else None: the first pass
        gathers it.
    pending : a reader's `Pending` checks, settled by the first pass.
    ledger : the passes over the log (`Ledger`), shared with the arrays made from it.
    """

    def __init__(
        self,
        array,
        survey: Survey | None = None,
        *,
        pending: Pending | None = None,
        ledger: Ledger | None = None,
    ):
        self.ledger = ledger or Ledger()
        if any(np.isnan(size) for size in array.chunks[0]):
            started = time.perf_counter()
            array = array.compute_chunk_sizes()  # one pass: the rows of every block
            self.ledger.record("count", time.perf_counter() - started)
        self.array = _whole_rows(array)
        self._survey = survey
        self._cache: dict = {}
        self.pending = pending

    @property
    def passes(self) -> int:
        """How many passes over the log's data have run (the read and the survey included)."""
        return self.ledger.passes

    @property
    def timings(self) -> list:
        """(what, seconds) of every pass over the log (`Ledger`). [s]"""
        return self.ledger.timings

    @property
    def surveyed(self) -> bool:
        """Whether the survey is gathered (else the next pass gathers it)."""
        return self._survey is not None

    def rebuilt(self, array) -> None:
        """Take another Dask array of the same log (the blocks' rows counted): the survey and
        the rows kept from the old one are dropped."""
        self.array = _whole_rows(array)
        self._survey, self._cache = None, {}

    def reread(self, array) -> None:
        """Take another Dask array of the same rows (read with fewer checks): the survey and the
        rows kept stay."""
        self.array = _whole_rows(array)

    @property
    def shape(self) -> tuple:
        return tuple(int(s) for s in self.array.shape)

    @property
    def ndim(self) -> int:
        return self.array.ndim

    @property
    def dtype(self):
        return np.dtype(float)

    def __len__(self) -> int:
        return self.shape[0]

    def __array__(self, dtype=None, copy=None):
        raise TypeError(
            "a Dask log is not turned into one numpy array (it may not fit in memory); use "
            "nlpcal.passes.reduce for a pass over its blocks"
        )

    def __mul__(self, factor) -> LazySamples:
        factor = float(factor)
        if not factor > 0:
            raise ValueError("LazySamples scale by a positive factor only")
        if self.pending is not None:  # the reader's checks settle on the log as read
            survey_together(self)
        survey = self._survey.scaled(factor) if self._survey is not None else None
        return LazySamples(self.array * factor, survey, ledger=self.ledger)

    __rmul__ = __mul__

    @property
    def n(self) -> int:
        return self.shape[0]

    def steps(self) -> tuple:
        """The strides of the survey's subsamples for this many rows."""
        return tuple(sorted({max(1, self.n // size) for size in SURVEY_SIZES}))

    def survey(self) -> Survey:
        """What one pass gathers (run now unless already run, or gathered with others by
        `survey_together`)."""
        if self._survey is None:
            survey_together(self)
        return self._survey  # type: ignore[return-value]

    def __getitem__(self, key) -> np.ndarray:
        """Rows as a numpy array: a slice of rows (with a stride), from the survey when it has
        them, else computed (and kept); `values[rows, columns]` takes columns of them."""
        rows, columns = (key[0], key[1:]) if isinstance(key, tuple) else (key, ())
        if not isinstance(rows, slice):
            raise TypeError("LazySamples take a slice of rows")
        values = self._rows(*rows.indices(self.n))
        return values[(slice(None), *columns)] if columns else values

    def _rows(self, start: int, stop: int, step: int) -> np.ndarray:
        strided = start == 0 and stop == self.n and step in self.steps()
        survey = self.survey() if strided else self._survey  # the survey has them
        if survey is not None and step > 0:
            if step == 1 and start == 0 and stop <= survey.head.shape[0]:
                return survey.head[:stop]
            if start == 0 and stop == self.n and step in survey.rows:
                return survey.rows[step]
        head = self._cache.get("head")
        if head is not None and start == 0 and step == 1 and stop <= head.shape[0]:
            return head[:stop]  # the first rows, read before the survey
        key = (start, stop, step)
        if key not in self._cache:  # the first rows: from the first blocks, not a pass
            import dask

            started = time.perf_counter()
            wanted = [self.array[start:stop:step]]
            if start == 0 and step > 1 and head is None:  # the leading rows from the same read
                wanted.append(self.array[: min(SURVEY_HEAD, self.n)])
            values = [np.asarray(v, dtype=float) for v in dask.compute(*wanted)]
            self.ledger.record("head", time.perf_counter() - started, whole=False)
            self._cache[key] = values[0]
            if len(values) > 1:
                self._cache["head"] = values[1]
            elif start == 0 and step == 1 and stop > (0 if head is None else head.shape[0]):
                self._cache["head"] = values[0]
        return self._cache[key]

    def mean(self, axis=None):
        """The mean over the rows (per column for samples). [unit of the values]"""
        mean = self.survey().total / self.n
        return float(mean[0]) if self.ndim == 1 and axis is None else mean

    def block_offsets(self) -> list:
        """(start, stop) of the rows of every block."""
        bounds = np.concatenate([[0], np.cumsum(self.array.chunks[0])]).astype(int)
        return list(zip(bounds[:-1].tolist(), bounds[1:].tolist()))

    def blocks(self, chunks=None) -> list:
        """One Dask delayed object per block of rows (rechunked to `chunks` along the rows when
        given). Not optimised: a fused graph would give the read of a block a key of its own in
        each array made from it (the samples, a reference column, a reader's checks), and one
        pass would read the block once for each."""
        array = self.array if chunks is None else self.array.rechunk({0: chunks})
        return list(array.to_delayed(optimize_graph=False).ravel())


def survey_together(*values) -> None:
    """Survey every `LazySamples` among `values` that has no survey yet (and settle a reader's
    pending checks), in passes of their own: a pair of arrays of the same rows (samples and
    their reference series) in one pass, so that arrays made from the same files read each
    block once. The survey usually comes along with the first pass instead (`reduce`)."""
    pending = [v for v in values if isinstance(v, LazySamples) and not v.surveyed]
    while pending:
        first = pending.pop(0)
        partner = next((v for v in pending if v.shape[0] == first.shape[0]), None)
        if partner is not None:
            pending.remove(partner)
        _reduce_dask(first, partner, nothing, no_merge)


def nothing(block, reference) -> None:
    """The work of a pass that only gathers the survey (`survey_together`)."""
    return None


def no_merge(first, second) -> None:
    return None


@dataclass(frozen=True)
class Surveying:
    """The work of a pass that also gathers the survey of its rows (`survey_block`), and of the
    rows of a reference series, on the way: one task per block does both, so that no survey
    needs a pass of its own.

    work : the pass's own work; indexed : whether it takes the block's first row.
    steps, reference_steps : the strides of the surveys' subsamples, None for no survey.
    """

    work: Callable
    indexed: bool
    steps: tuple | None
    reference_steps: tuple | None

    def __call__(self, block, reference, start: int) -> tuple:
        """(the work's partial result, the samples' survey, the reference's survey)."""
        with np.errstate(all="ignore"):  # values checked once surveyed
            result = self.work(block, reference, *((start,) if self.indexed else ()))
            mine = None if self.steps is None else survey_block(block, start, self.steps)
            theirs = None
            if self.reference_steps is not None:
                theirs = survey_block(reference, start, self.reference_steps)
        return result, mine, theirs


@dataclass(frozen=True)
class SurveyingMerge:
    """The merge of `Surveying` partial results: the work's own merge, and the surveys'."""

    merge: Callable

    def __call__(self, first: tuple, second: tuple) -> tuple:
        return (
            self.merge(first[0], second[0]),
            merge_optional(first[1], second[1]),
            merge_optional(first[2], second[2]),
        )


def lazy(*values) -> tuple:
    """`values` with every Dask array as `LazySamples` (not surveyed: the first pass gathers
    their survey); other values as they are."""
    return tuple(LazySamples(v) if is_dask(v) else v for v in values)


def as_rows(values):
    """In-memory values as a float numpy array (a memory map stays mapped); Dask arrays as
    `LazySamples`; `LazySamples` as they are."""
    if isinstance(values, LazySamples):
        return values
    if is_dask(values):
        return LazySamples(values)
    return np.asarray(values, dtype=float)


def is_lazy(values) -> bool:
    """Whether `values` stay where they are (a Dask array or `LazySamples`) rather than in
    memory."""
    return is_dask(values) or isinstance(values, LazySamples)


def scaled(values, factor: float):
    """An array times a positive `factor`: in memory as float64 (the same array when the
    factor is 1), `LazySamples` scaled block by block in each pass."""
    if not isinstance(values, LazySamples):
        values = np.asarray(values, dtype=float)
    return values if factor == 1.0 else values * factor  # base units pass through uncopied


def axis_ranges(array, chunk_rows: int) -> tuple:
    """Per-column minimum and maximum of (N, 3) rows, NaN where a column has a NaN: in chunks
    of `chunk_rows` (a memory map stays mapped), or those of a Dask log's survey."""
    if isinstance(array, LazySamples):
        survey = array.survey()
        return survey.low, survey.high
    low, high = np.full(3, np.inf), np.full(3, -np.inf)
    for start in range(0, array.shape[0], chunk_rows):
        chunk_low, chunk_high = column_ranges(array[start : start + chunk_rows])
        low, high = np.minimum(low, chunk_low), np.maximum(high, chunk_high)
    return low, high


#: Rows of the first block of a Dask log read for what must be known before the first pass
#: (the frame of its moments, the plausibility of its unit), at most. [1]
FIRST_BLOCK_ROWS = 2**20
#: The most rows a sphere fit or a unit's plausibility reads of a log: an even stride of it
#: (`sample_stride`). [1]
SAMPLE_POINTS = 20_000


def sample_stride(rows: int, points: int = SAMPLE_POINTS) -> int:
    """The stride of an even subsample of about `points` of `rows` rows (all of fewer)."""
    return max(1, rows // points)


def first_block_rows(values) -> slice:
    """The rows a sphere fit or a unit check reads of the first rows of a log (at most
    FIRST_BLOCK_ROWS; of a Dask log its first block, read apart: not a pass), an even stride of
    them (`sample_stride`): the very rows they would take of all those first rows."""
    rows = min(values.shape[0], FIRST_BLOCK_ROWS)
    if isinstance(values, LazySamples):
        rows = min(rows, values.block_offsets()[0][1])
    return slice(0, rows, sample_stride(rows))


def first_block_sample(values) -> np.ndarray:
    """The values of `first_block_rows`: of a Dask log, only they come to this process (0.5 MB
    of a block of 2^20 rows of three columns, 24 MB); the block is read where it lies. [unit of
    the values]"""
    return np.asarray(values[first_block_rows(values)], dtype=float)


def in_memory(values, most: int) -> np.ndarray:
    """Values as a float numpy array: in memory as they are, `LazySamples` an even stride of at
    most about `most` rows (from the survey when it has them)."""
    if isinstance(values, LazySamples):
        return values[:: max(1, values.n // most)]
    return np.asarray(values, dtype=float)


def mean_square(values) -> float:
    """The mean of the squares of a series (of a Dask one: from its survey). [unit^2]"""
    if isinstance(values, LazySamples):
        return float(values.survey().squares[0]) / values.n
    return float(np.mean(np.asarray(values) ** 2))


def reference_chunk(reference, start: int, stop: int):
    """The part of a reference (None, a float or an (N,) array) for rows start:stop."""
    if reference is None or np.ndim(reference) == 0:
        return reference
    return reference[start:stop]


def reduce(samples, reference, work, merge, chunk_rows: int, indexed: bool = False):
    """One pass over the samples: work(rows, reference rows) per block, merged in row order.

    samples : (N, k) rows, in memory or `LazySamples`. [unit]
    reference : None, a number, or (N,) values on the same rows (in memory or `LazySamples`).
    work : (block of rows, its reference) -> a partial result; it must loop over chunks of
        `chunk_rows` itself, the blocks being shares of the rows in memory and Dask chunks.
    merge : (earlier partial, later partial) -> the partial of both.
    indexed : work takes a third argument, the index of the block's first row in the log.
    """
    if isinstance(samples, LazySamples) or isinstance(reference, LazySamples):
        return _reduce_dask(samples, reference, work, merge, indexed)

    def share(begin: int, end: int):
        where = (begin,) if indexed else ()
        return work(samples[begin:end], reference_chunk(reference, begin, end), *where)

    parts = chunks.map_shares(share, samples.shape[0], chunk_rows)
    result = parts[0]
    for part in parts[1:]:
        result = merge(result, part)
    return result


def _reduce_dask(samples, reference, work, merge, indexed: bool = False):
    """One pass on the current Dask scheduler: the survey of every `LazySamples` not yet
    surveyed comes along (`Surveying`), and the reader's `Pending` checks settle; a pass whose
    checks found the blocks not as declared runs again on the rebuilt arrays."""
    import dask
    import dask.array as da

    survey_samples = isinstance(samples, LazySamples)
    if not survey_samples:  # a Dask reference with samples in memory
        blocks = (reference.array.chunks[0], -1)
        samples = LazySamples(
            da.from_array(np.asarray(samples), chunks=blocks), ledger=reference.ledger
        )
    ledgers = {id(v.ledger): v.ledger for v in (samples, reference) if isinstance(v, LazySamples)}
    while True:
        whole, surveys = _pass_tree(samples, reference, work, merge, indexed, survey_samples)
        pending = list(
            {
                id(v.pending): v.pending
                for v in (samples, reference)
                if isinstance(v, LazySamples) and v.pending is not None
            }.values()
        )
        started = time.perf_counter()
        with chunks.single_blas():  # Dask threads run blocks side by side
            result, *checked = dask.compute(whole, *[p.parts for p in pending])
        stands = all([p.settle(values) for p, values in zip(pending, checked)])
        name = "survey" if work is nothing else type(work).__name__
        for ledger in ledgers.values():
            ledger.record(
                name + (" + survey" if surveys and name != "survey" else ""),
                time.perf_counter() - started,
            )
        if stands:
            break
    if not surveys:
        return result
    result, mine, theirs = result
    if mine is not None:  # the survey holds the first rows: drop those read before it
        samples._survey, samples._cache = mine, {}
    if theirs is not None:
        reference._survey, reference._cache = theirs, {}
    return result


def _pass_tree(samples, reference, work, merge, indexed: bool, survey_samples: bool) -> tuple:
    """(the delayed result of a pass, whether it gathers surveys) over the blocks of
    `samples` and the same rows of `reference`."""
    import dask

    offsets = samples.block_offsets()
    if isinstance(reference, LazySamples):
        rows = samples.array.chunks[0]
        references = reference.blocks(None if reference.array.chunks[0] == rows else rows)
        reference_steps = None if reference.surveyed else reference.steps()
    else:  # in memory: each task takes its own rows of the reference
        references = [reference_chunk(reference, start, stop) for start, stop in offsets]
        reference_steps = None
    steps = samples.steps() if survey_samples and not samples.surveyed else None
    surveys = steps is not None or reference_steps is not None
    if surveys:
        work, merge = Surveying(work, indexed, steps, reference_steps), SurveyingMerge(merge)
    parts = [
        dask.delayed(work)(block, ref, *((start,) if indexed or surveys else ()))
        for block, ref, (start, _) in zip(samples.blocks(), references, offsets)
    ]
    return tree(parts, merge), surveys


def tree(parts: list, merge):
    """Merge delayed partial results pairwise, neighbours with neighbours, until one is left."""
    import dask

    while len(parts) > 1:
        pairs = [
            dask.delayed(merge)(parts[i], parts[i + 1]) if i + 1 < len(parts) else parts[i]
            for i in range(0, len(parts), 2)
        ]
        parts = pairs
    return parts[0]
