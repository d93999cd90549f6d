"""Properties behind the speed of nlpcal (not timings: those live in benchmarks/)."""

import tracemalloc

import numpy as np
import pandas as pd
import pytest

from nlpcal import calibrate
from nlpcal.errors import InputError
from nlpcal.io import csv_to_memmap
from nlpcal.moments import CHUNK_ROWS, accumulate
from synthetic import PAPER_FIELD, PAPER_TRUTH, make_log


def _peak_on_memory_map(tmp_path, n: int) -> tuple:
    """(the peak of memory allocated while calibrating a memory-mapped log of n samples, the
    log's size, the result) [bytes]"""
    samples, _ = make_log(n=n, noise=1.0, seed=12)
    path = tmp_path / f"log-{n}.f8"
    mapped = np.memmap(path, dtype=np.float64, mode="w+", shape=samples.shape)
    mapped[:] = samples
    mapped.flush()
    del samples
    log = np.memmap(path, dtype=np.float64, mode="r", shape=mapped.shape)
    tracemalloc.start()
    result = calibrate(log, method="joint", reference_field=PAPER_FIELD)
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    return peak, log.nbytes, result


def test_memory_stays_o_chunk_on_a_memory_mapped_log(tmp_path):
    # The calibration allocates a few chunk buffers per thread (the data pass's chunk of
    # CHUNK_ROWS rows and the kernel's monomials, the pass after the solve's work arrays of
    # SCORE_CHUNK_ROWS columns), whatever the length of the log: four times the samples, the
    # same peak (within what a sample's frame fit and the solver's bookkeeping add).
    small, _, _ = _peak_on_memory_map(tmp_path, 500_000)
    peak, size, result = _peak_on_memory_map(tmp_path, 2_000_000)
    assert peak <= 1.2 * small + 2**20
    assert peak < 0.4 * size  # 48 MB of data
    assert abs(result.parameters["z_x"] - PAPER_TRUTH["z_x"]) < 0.1


def test_csv_streamed_into_a_memmap_matches_pandas(tmp_path):
    samples, _ = make_log(n=3000, noise=1.0, seed=13)
    frame = pd.DataFrame(samples, columns=["bx", "by", "bz"])
    frame["proton_nT"] = PAPER_FIELD
    frame["label"] = "a"
    path = tmp_path / "log.csv"
    frame.to_csv(path, index=False)
    mapped = csv_to_memmap(path, extra_columns=["proton_nT"], chunk_rows=700)
    assert isinstance(mapped.values, np.memmap)
    assert mapped.columns == ["bx", "by", "bz", "proton_nT"]
    np.testing.assert_allclose(
        mapped.values, pd.read_csv(path)[mapped.columns].to_numpy(), rtol=1e-15
    )
    bad = tmp_path / "bad.csv"
    bad.write_text("bx,by,bz\n1,2,3\n4,x,6\n")
    with pytest.raises(InputError, match="non-numeric"):
        csv_to_memmap(bad)
    assert csv_to_memmap(bad, drop_invalid=True).dropped == 1


def test_the_gram_matrix_covers_every_sample_whatever_the_chunking():
    # The moments are the mean over all samples of products of monomials of the centred, scaled
    # sample: checked here against a direct evaluation of a few of them, for N that are not
    # multiples of the chunk size, and for several chunk sizes and thread shares.
    from nlpcal.moments import MONOMIALS, layout

    for n in (100, CHUNK_ROWS + 1, 3 * CHUNK_ROWS + 17):
        samples, _ = make_log(n=n, noise=1.0, seed=n)
        moments = accumulate(samples, PAPER_FIELD)
        assert moments.gram.shape == (46, 46) and moments.n == n
        d = (samples - moments.frame.centre) / moments.length
        a = np.einsum("ij,ij->i", d, d) - 1.0
        keys = layout(False).keys
        for i, j in (
            (1, 1),
            (34, 34),
            (7, 20),
            (keys.index((0, 1, (0, 0, 0))), 0),
            (keys.index((0, 2, (0, 0, 0))), 34),
        ):

            def feature(k):
                _, a_power, exps = keys[k]
                return np.prod(d ** np.array(exps), axis=1) * a**a_power

            direct = np.mean(feature(i) * feature(j))
            assert moments.gram[i, j] == pytest.approx(direct, rel=1e-11, abs=1e-15)
        assert len(MONOMIALS) == 35
        again = accumulate(samples, PAPER_FIELD, chunk_rows=1000, frame=moments.frame)
        np.testing.assert_allclose(again.gram, moments.gram, rtol=1e-11, atol=1e-15)
