"""Rows that are not readings: exact-zero field vectors and vectors repeated row after row.

A magnetometer in the Earth's field never reads exactly (0, 0, 0) on all three axes: such a row is
a logger's start-up or no-data record, and one of them among a few thousand samples can double the
spread left after calibration. Those rows are always left out, and counted.

A field vector equal to the one of the row before is either a logger that reads faster than the
sensor updates (every reading then appears several times) or a sensor that stuck. Either way the
repeats are not new information, although a fit counts them as such. They are reported when they
are many (REPEATS_NOTE_FRACTION) or run long (STUCK_RUN), and dropped with drop_invalid, keeping
the first row of each run.
"""

from __future__ import annotations

import numpy as np

#: Report repeated vectors when they are at least this fraction of the rows. [1]
REPEATS_NOTE_FRACTION = 0.05
#: ... or when one vector is read this many times in a row. [rows]
STUCK_RUN = 10
#: Most row numbers quoted in a message.
QUOTED_ROWS = 5


def _runs(flags: np.ndarray) -> tuple:
    """(starts, lengths) of the runs of True in a boolean array."""
    padded = np.concatenate([[0], flags.astype(np.int8), [0]])
    edges = np.diff(padded)
    starts = np.flatnonzero(edges == 1)
    return starts, np.flatnonzero(edges == -1) - starts


def _numbers(data_rows: np.ndarray | None, index):
    """The row numbers of the rows at `index` (an array or one position) of a chunk whose rows
    are numbered `data_rows` (None: 1 to N)."""
    return index + 1 if data_rows is None else data_rows[index]


def quoted_rows(count: int, rows: list) -> str:
    """Row numbers for a message: "5, 17" of the first QUOTED_ROWS `rows`, with ", ..." when
    `count` rows are meant."""
    more = ", ..." if count > len(rows) else ""
    return ", ".join(str(r) for r in rows) + more


class RowScreen:
    """Screens the field vectors of a log, chunk after chunk, and says what it left out.

    drop_repeats : drop vectors equal to the previous row's (keeping the first of each run).
    """

    def __init__(self, drop_repeats: bool = False):
        self.drop_repeats = drop_repeats
        self.rows = 0
        self.zero_rows: list = []
        self.zeros = 0
        self.repeats = 0
        self.longest = 0  # repeats in the longest run (the run holds one reading more)
        self.longest_at = 0  # data row of the first reading of the longest run
        self._previous: np.ndarray | None = None
        self._run = 0
        self._run_at = 0
        self._previous_row = 0

    def keep(self, field: np.ndarray, data_rows: np.ndarray | None = None) -> np.ndarray:
        """Mask of the rows of `field` (N, 3) to keep; `data_rows` are their 1-based row numbers
        in the file's data, for messages (None: 1 to N)."""
        field = np.asarray(field, dtype=float)
        n = field.shape[0]
        self.rows += n
        x, y, z = field[:, 0], field[:, 1], field[:, 2]  # columns: faster than axis=1 reductions
        zero = (x == 0.0) & (y == 0.0) & (z == 0.0)
        zeros = int(np.count_nonzero(zero))
        if zeros:
            self.zeros += zeros
            room = max(QUOTED_ROWS - len(self.zero_rows), 0)
            quoted = np.flatnonzero(zero)[:room]
            self.zero_rows.extend(int(r) for r in _numbers(data_rows, quoted))
        repeat = np.zeros(n, dtype=bool)
        if n:
            np.equal(x[1:], x[:-1], out=repeat[1:])
            repeat[1:] &= y[1:] == y[:-1]
            repeat[1:] &= z[1:] == z[:-1]
            if self._previous is not None:
                repeat[0] = bool(np.all(field[0] == self._previous))
            if zeros:
                repeat &= ~zero
        repeats = int(np.count_nonzero(repeat))
        self.repeats += repeats
        self._count_runs(repeat, repeats, data_rows)
        if n:
            self._previous = field[-1].copy()
        if self.drop_repeats and repeats:
            return ~(zero | repeat)
        return ~zero

    def _count_runs(self, repeat: np.ndarray, repeats: int, data_rows) -> None:
        """Track the longest run of repeats, across chunks (`repeats` of them in this one: none,
        and no run is looked for)."""
        n = repeat.shape[0]
        if n == 0:
            return
        starts, lengths = _runs(repeat) if repeats else ((), ())
        run = 0
        for start, chunk_length in zip(starts, lengths):
            length = int(chunk_length)
            at = int(_numbers(data_rows, start - 1)) if start > 0 else self._previous_row
            if start == 0 and self._run:  # the run goes on from the previous chunk
                length, at = length + self._run, self._run_at
            if length > self.longest:
                self.longest, self.longest_at = length, at
            if start + chunk_length == repeat.shape[0]:
                run, self._run_at = length, at
        self._run = run
        self._previous_row = int(_numbers(data_rows, n - 1))

    def notes(self, kept: bool = False) -> list:
        """What was left out or looks wrong, one sentence each; `kept`: the rows that are not
        readings were kept in place, marked (`nlpcal apply`'s `valid` column), not left out."""
        notes = []
        if self.zeros:
            where = quoted_rows(self.zeros, self.zero_rows)
            what = f"{self.zeros} row(s) whose field vector is exactly (0, 0, 0) (data row {where})"
            if kept:
                notes.append(
                    f"{what} are a logger's start-up or no-data record, not readings: kept with "
                    f"their raw values, marked valid 0"
                )
            else:
                notes.append(
                    f"left out {what}: a logger's start-up or no-data record, not a reading"
                )
        many = self.repeats >= REPEATS_NOTE_FRACTION * max(self.rows, 1)
        stuck = self.longest + 1 >= STUCK_RUN
        if self.repeats and (many or stuck or self.drop_repeats):
            share = self.repeats / max(self.rows, 1)
            what = (
                f"{self.repeats} of {self.rows} rows ({share:.0%}) repeat the field vector of "
                f"the row before (the longest run: {self.longest + 1} identical readings from "
                f"data row {self.longest_at})"
            )
            if self.drop_repeats and kept:
                notes.append(
                    f"marked the repeats valid 0, raw values kept (--drop-invalid): {what}"
                )
            elif self.drop_repeats:
                notes.append(f"dropped the repeats (--drop-invalid): {what}")
            else:
                notes.append(
                    f"{what}: the logger read faster than the sensor updated, or the sensor "
                    f"stuck; each repeat counts as a new sample; --drop-invalid keeps the first "
                    f"row of each run"
                )
        return notes
