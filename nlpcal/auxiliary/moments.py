"""The moments of the |B1| objectives with auxiliary channels: the feature group they add.

With K channels scaled to order one, c~ = (c - c0) / cs (`ChannelFrame`), the corrected field
of (*) in `nlpcal.auxiliary.model` in the frame of `nlpcal.moments` is B1 / L = M y with

    y = d - z~ - W c~,    z~ = (Z_p + V c0 - centre) / L,    W = V diag(cs) / L,

so |B1|^2 / L^2 = v^T Q v with v = (d, c~, 1) and Q = E^T A E, E = [I, -W, -z~], A = M^T M.
Hence u = a + e . psi' as in `nlpcal.moments`, psi' now holding the (4 + K)(5 + K) / 2 products
v_p v_q (p <= q): the ten of the nine-parameter model, d c~ (3K), c~ c~^T and c~ (K each, and
their products). The features are the distinct gamma^j a^k m over the monomials m of (d, c~) of
degree <= 4: 86 for one channel with gamma constant, 148 for two. Their Gram matrix is a
selection of its distinct entries, the moments gamma^j a^k m (791 for one channel, 1 897 for two
with gamma constant; (M1) in `nlpcal.moments`), gathered in one pass (`nlpcal.monomials`),
additive over blocks (numpy, memory maps and Dask alike, `nlpcal.passes`): the
problem's size depends on K, never on N.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cache

import numpy as np

from .. import compiled
from .. import moments as mom
from ..passes import LazySamples, reduce

#: Rows of the strided subsample the channels' frame and the identifiability checks read.
SUBSAMPLE = 20_000


@dataclass(frozen=True)
class ChannelFrame:
    """The centre and scale of the channels: c~ = (c - centre) / scale.

    centre, scale : (K,) the mean and the standard deviation of each channel on an even
        stride of the log. [channel unit]
    """

    centre: np.ndarray
    scale: np.ndarray


def channel_frame(channels) -> ChannelFrame:
    """The `ChannelFrame` of (N, K) channel values on an even stride of at most SUBSAMPLE rows."""
    strided = subsample(channels)
    return ChannelFrame(strided.mean(axis=0), strided.std(axis=0))


def subsample(values) -> np.ndarray:
    """Rows values[::step] of at most about SUBSAMPLE rows, as numpy (a Dask log's from its
    survey)."""
    step = max(1, values.shape[0] // SUBSAMPLE)
    return np.asarray(values[::step], dtype=float)


def pair_exponents(channels: int) -> tuple:
    """The exponents over (d, c~) of psi'_j = v_p v_q, p <= q, v = (d, c~, 1)."""
    size = 3 + channels
    exps = []
    for p in range(size + 1):
        for q in range(p, size + 1):
            e = [0] * size
            for index in (p, q):
                if index < size:
                    e[index] += 1
            exps.append(tuple(e))
    return tuple(exps)


@cache
def channel_layout(varying_gamma: bool, channels: int) -> mom.Layout:
    """The distinct features of the objective with K channels (`nlpcal.moments.Layout`)."""
    psi_exps = pair_exponents(channels)
    keys: list = []
    index: dict = {}

    def key(gamma_power, a_power, exps):
        k = (gamma_power if varying_gamma else 0, a_power, exps)
        if k not in index:
            index[k] = len(keys)
            keys.append(k)
        return index[k]

    zero = (0,) * (3 + channels)
    if not varying_gamma:
        for exps in mom.monomials(4, 3 + channels)[0]:
            key(0, 0, exps)
    one = key(0, 0, zero)
    psi = tuple(key(1, 0, e) for e in psi_exps)
    pair = {
        (k, m): key(2, 0, tuple(np.add(psi_exps[k], psi_exps[m])))
        for k in range(len(psi_exps))
        for m in range(k, len(psi_exps))
    }
    a = key(0, 1, zero)
    apsi = tuple(key(1, 1, e) for e in psi_exps)
    a2 = key(0, 2, zero)
    return mom.Layout(varying_gamma, tuple(keys), one, a, a2, psi, pair, apsi)


@cache
def channel_moments(varying_gamma: bool, channels: int) -> tuple:
    """The distinct moments of `channel_layout`'s Gram matrix over (gamma, a, d, c~) and the
    position of each Gram entry among them (`nlpcal.moments.pair_moments`)."""
    return mom.pair_moments(channel_layout(varying_gamma, channels))


@dataclass(frozen=True)
class ChannelGram:
    """The work of the pass on one block: its partial Gram matrix of the features (a sum).

    centre, length : the frame of d. [field unit]  channels : the `ChannelFrame`.
    reference : None or a constant F [field unit]; a series comes with the rows, as the last
        column of the block of extra values.
    """

    centre: np.ndarray
    length: float
    channels: ChannelFrame
    series: bool
    chunk_rows: int = mom.CHUNK_ROWS
    fast: bool = False  # the compiled kernel sums the moments (`nlpcal.compiled.use`)

    def __call__(self, samples, extra) -> np.ndarray:
        """The sums of the distinct moments of the block (`channel_moments`)."""
        samples, extra = np.asarray(samples, dtype=float), np.asarray(extra, dtype=float)
        k = self.channels.centre.size
        moments = channel_moments(self.series, k)[0]
        sums = moments.empty()
        rows = samples.shape[0]
        variables = np.empty((len(mom.VARIABLES) + k, max(1, min(self.chunk_rows, rows))))
        for start in range(0, rows, self.chunk_rows):
            stop = min(start + self.chunk_rows, rows)
            chunk = variables[:, : stop - start]
            gamma, a, d, c = chunk[0], chunk[1], chunk[2:5], chunk[5:]
            np.divide((samples[start:stop] - self.centre).T, self.length, out=d)
            np.divide(
                (extra[start:stop, :k] - self.channels.centre).T,
                self.channels.scale[:, None],
                out=c,
            )
            np.einsum("ij,ij->j", d, d, out=a)
            weight = None
            if self.series:
                np.divide(self.length, extra[start:stop, k], out=gamma)
                gamma *= gamma
                a *= gamma
                weight = 1.0 / gamma  # w_i = F_i^2 / L^2
            a -= 1.0
            moments.add(sums, chunk, weight, self.fast)
        return moments.values(sums)


@dataclass
class ChannelMoments:
    """The Gram matrix of the features with K channels, and the frames it was taken in.

    gram : (size, size) mean of f f^T (weighted by F_i^2 / L^2 for a series).
    frame : `nlpcal.moments.Frame` of d. length : L. [field unit]
    channels : `ChannelFrame`. reference : "none", "constant" or "series". n : samples.
    """

    gram: np.ndarray
    frame: mom.Frame
    length: float
    channels: ChannelFrame
    reference: str
    n: int

    @property
    def layout(self) -> mom.Layout:
        return channel_layout(self.reference == "series", self.channels.centre.size)


def accumulate_channels(samples, channels, reference, frame: mom.Frame, length: float, kind: str):
    """One pass over the samples and their channels (and a reference series) that builds the
    Gram matrix of `channel_layout`.

    samples : (N, 3) raw B_M [field unit]; channels : (N, K) [channel unit]; reference : None,
    F or (N,) F_i [field unit]; frame, length : the frame of d; kind : "none", "constant" or
    "series".
    """
    cframe = channel_frame(channels)
    extra = channels if kind != "series" else stacked(channels, reference)
    n = samples.shape[0]
    fast = compiled.use(n)
    work = ChannelGram(frame.centre, length, cframe, kind == "series", fast=fast)
    sums = reduce(samples, extra, work, np.add, mom.CHUNK_ROWS)
    gram = sums[channel_moments(kind == "series", cframe.centre.size)[1]] / n
    return ChannelMoments(gram, frame, length, cframe, kind, n)


def dask_rows(*values) -> list:
    """Dask arrays of `values` (LazySamples, or arrays in memory) in the row blocks of the
    first, every column in one block."""
    import dask.array as da

    arrays = [
        v.array if isinstance(v, LazySamples) else da.from_array(np.asarray(v)) for v in values
    ]
    rows = arrays[0].chunks[0]
    return [a.rechunk({0: rows, **({1: -1} if a.ndim == 2 else {})}) for a in arrays]


def stacked(channels, reference):
    """The channels and the reference series side by side, (N, K + 1), in memory or on Dask."""
    if isinstance(channels, LazySamples) or isinstance(reference, LazySamples):
        import dask.array as da

        lazy_channels, lazy_reference = dask_rows(channels, reference)
        return LazySamples(da.concatenate([lazy_channels, lazy_reference[:, None]], axis=1))
    return np.column_stack([np.asarray(channels, dtype=float), np.asarray(reference, dtype=float)])
