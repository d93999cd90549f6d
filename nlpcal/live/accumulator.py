"""The moments of a stream (`nlpcal.moments`), gathered as the samples arrive.

The Gram matrix G of `nlpcal.moments` is a sum over samples, so each batch of samples adds its
own block of distinct moments (`nlpcal.moments.MomentBlock`, the Gram matrix assembled from
them) and the problem the solver sees keeps its fixed size.
The sum needs a frame (the centre and scale of d = (b - c) / L), fixed before the first sample
is added: it is the sphere fitted to the first `FRAME_SAMPLES` samples. A sensor turned only a
little at first gives a poor sphere; whenever the sphere fitted to all the samples so far moves
away from the frame by more than `FRAME_TOLERANCE` of its radius, the sum restarts in the new
frame from the recorded samples (one pass), so the moments never carry the cancellation of a
frame far from the data.

With a forgetting factor lambda < 1, sample i of N enters with weight lambda^(N - 1 - i): the
sum is multiplied by lambda^k before a batch of k samples is added, and the weights' sum (the
effective number of samples) is what the standard errors count (`Moments.weight_sum`). The
Table 1 statistics of the raw |B_M| keep every sample.
"""

from __future__ import annotations

import numpy as np

from ..moments import (
    CHUNK_ROWS,
    Frame,
    MomentBlock,
    Moments,
    gram_moments,
    moments_from,
    sphere_frame,
)
from ..statistics import MagnitudeStats

#: Samples the first frame is fitted to (about a second of a 75 Hz sensor).
FRAME_SAMPLES = 64
#: A frame whose centre lies further than this fraction of the radius from the sphere fitted to
#: all the samples so far, or whose radius differs from that sphere's by more, is replaced. [1]
FRAME_TOLERANCE = 0.1
#: Rows the sample record grows by when it is full.
GROWTH_ROWS = 4096


class StreamMoments:
    """The moments of the samples added so far, in base units.

    reference : None (no reference field) or a constant field F. [field unit]
    forgetting : lambda, the weight of a sample relative to the next one's (1: every sample
        counts alike). [1]
    """

    def __init__(self, reference: float | None = None, forgetting: float = 1.0):
        self.reference = reference
        self.forgetting = float(forgetting)
        self._record = np.empty((GROWTH_ROWS, 3))
        self.n = 0
        self.frame: Frame | None = None
        self.reframed = 0  # how many times the sum restarted in a new frame
        self._added = 0  # samples summed into the Gram matrix
        self._reset_sums()

    @property
    def samples(self) -> np.ndarray:
        """(n, 3) every sample added, in order (a view of the record). [field unit]"""
        return self._record[: self.n]

    def add(self, rows) -> None:
        """Append samples (k, 3) and add them to the sums (once the frame is fixed). [field
        unit]"""
        rows = np.asarray(rows, dtype=float).reshape(-1, 3)
        if self.n + len(rows) > len(self._record):
            grown = np.empty((max(2 * len(self._record), self.n + len(rows)), 3))
            grown[: self.n] = self.samples
            self._record = grown
        self._record[self.n : self.n + len(rows)] = rows
        self.n += len(rows)
        if self.frame is None and self.n >= FRAME_SAMPLES:
            self._restart(sphere_frame(self.samples))
        elif self.frame is not None:
            self._sum_to_end()

    def check_frame(self) -> bool:
        """Restart the sums in the sphere fitted to all the samples when the frame has moved
        away from it (FRAME_TOLERANCE); True when it did."""
        if self.frame is None:
            return False
        fitted = sphere_frame(self.samples)
        moved = float(np.linalg.norm(fitted.centre - self.frame.centre))
        off = max(moved, abs(fitted.radius - self.frame.radius)) / fitted.radius
        if not off > FRAME_TOLERANCE:
            return False
        self._restart(fitted)
        self.reframed += 1
        return True

    def moments(self) -> Moments | None:
        """The moments of the samples so far (`nlpcal.moments.Moments`), or None before the
        frame is fixed."""
        if self.frame is None or self._weight <= 0:
            return None
        kind = "none" if self.reference is None else "constant"
        return moments_from(
            self._sums / self._weight,
            self.frame,
            self._length,
            self.n,
            kind,
            self._measured.result(),
            self._weight,
        )

    # --- the sums ---------------------------------------------------------------------------

    def _reset_sums(self) -> None:
        self._sums = np.zeros(gram_moments(False).size)
        self._measured = MagnitudeStats()
        self._weight = 0.0
        self._added = 0

    def _restart(self, frame: Frame) -> None:
        """Fix the frame and sum every recorded sample in it."""
        self.frame = frame
        self._length = frame.radius if self.reference is None else float(self.reference)
        head = self.samples[:1024]
        shift = float(np.sqrt(np.einsum("ij,ij->i", head, head)).mean())
        self._block = MomentBlock(frame.centre, self._length, False, shift)
        self._reset_sums()
        self._sum_to_end()

    def _sum_to_end(self) -> None:
        """Add the samples not summed yet, in blocks of CHUNK_ROWS rows (the rows of one block
        of `nlpcal.moments.accumulate`, so that a stream summed in one frame adds in the order
        of a log's pass)."""
        while self._added < self.n:
            stop = min(self.n, self._added + CHUNK_ROWS - self._added % CHUNK_ROWS)
            self._add_block(self.samples[self._added : stop])
            self._added = stop

    def _add_block(self, rows: np.ndarray) -> None:
        lam = self.forgetting
        if lam == 1.0:
            sums, measured, _ = self._block(rows, self.reference)
            weight = float(len(rows))
        else:  # lambda^(k - 1 - j) for row j of k: the newest row has weight one
            weights = lam ** np.arange(len(rows) - 1, -1, -1, dtype=float)
            block = MomentBlock(
                self._block.centre,
                self._block.length,
                False,
                self._block.shift,
                weight=lambda raw, ref: weights,
            )
            sums, measured, weight = block(rows, self.reference)
            decay = lam ** len(rows)
            self._sums *= decay
            self._weight *= decay
        self._sums += sums
        self._weight += weight
        self._measured = self._measured.merge(measured) if self._measured.n else measured
