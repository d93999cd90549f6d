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


def test_memory_stays_o_chunk_on_a_memory_mapped_log(tmp_path):
    samples, _ = make_log(n=1_000_000, noise=1.0, seed=12)
    path = tmp_path / "log.f8"
    mapped = np.memmap(path, dtype=np.float64, mode="w+", shape=samples.shape)
    mapped[:] = samples
    mapped.flush()
    del samples
    log = np.memmap(path, dtype=np.float64, mode="r", shape=mapped.shape)
    tracemalloc.start()
    result = calibrate(log, method="joint", reference_field=PAPER_FIELD)
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    # The data are 24 MB; the calibration allocates a few chunk buffers per thread
    # (about 50 x 8192 doubles each).
    assert peak < 0.4 * log.nbytes
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
    np.testing.assert_allclose(mapped.values, pd.read_csv(path)[mapped.columns].to_numpy(),
                               rtol=1e-15)
    bad = tmp_path / "bad.csv"
    bad.write_text("bx,by,bz\n1,2,3\n4,x,6\n")
    with pytest.raises(InputError, match="non-numeric"):
        csv_to_memmap(bad)
    assert csv_to_memmap(bad, drop_invalid=True).dropped == 1


def test_moment_cost_is_one_pass_with_fixed_size():
    # Whatever N, the moments have the same size; the pass reads each sample once.
    for n in (100, CHUNK_ROWS + 1, 3 * CHUNK_ROWS):
        samples, _ = make_log(n=n, noise=1.0, seed=n)
        moments = accumulate(samples, PAPER_FIELD)
        assert moments.gram.shape == (46, 46) and moments.n == n
        assert moments.gram[0, 0] == pytest.approx(1.0)
