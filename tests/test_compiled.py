"""The compiled kernel of the data pass (`nlpcal.compiled`) and when a pass uses it.

The compiled kernel must give the numpy kernel's moment sums to the rounding of float64 sums
(it adds the samples of a chunk in another order), for every moment set nlpcal gathers: the
nine-parameter objective's with a constant reference and with a series, the lag's, and the
auxiliary channels'; with and without weights, over chunks that end inside its step.
"""

import os
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

import nlpcal
from nlpcal import compiled
from nlpcal.auxiliary.moments import channel_moments
from nlpcal.calibration.scores import score_block_sums, score_terms
from nlpcal.cli import main
from nlpcal.errors import InputError
from nlpcal.lag import lag_moment_set
from nlpcal.moments import accumulate, gram_moments, layout
from nlpcal.robust import Loss
from synthetic import PAPER_FIELD, make_log

#: ||sums_compiled - sums_numpy|| / ||sums_numpy|| allowed: rounding of sums of O(1) terms.
SUMS_RTOL = 1e-12

EXAMPLE = Path(__file__).resolve().parents[1] / "data" / "example_zhou2010.csv"

needs_numba = pytest.mark.skipif(not compiled.available(), reason="numba is not installed")

MOMENT_SETS = {
    "constant": lambda: gram_moments(False),
    "series": lambda: gram_moments(True),
    "lag": lambda: lag_moment_set(layout(True))[0],
    "two channels": lambda: channel_moments(True, 2)[0],
}


def relative(new, old) -> float:
    return float(np.linalg.norm(new - old) / np.linalg.norm(old))


@needs_numba
@pytest.mark.parametrize("name", MOMENT_SETS)
@pytest.mark.parametrize("weighted", [False, True])
def test_the_compiled_kernel_sums_the_moments_of_the_numpy_kernel(name, weighted):
    moments = MOMENT_SETS[name]()
    variables_count = len(moments.keys[0])
    rng = np.random.default_rng(5)
    rows = 3 * compiled.STEP + 77  # the last step of the chunk is a short one
    variables = rng.normal(0.0, 0.6, (variables_count, rows))
    variables[0] = rng.uniform(0.8, 1.2, rows)  # gamma, a ratio of fields near one
    weight = rng.uniform(0.0, 2.0, rows) if weighted else None
    fast, slow = moments.empty(), moments.empty()
    for chunk in (slice(0, 1000), slice(1000, rows)):  # two chunks add to the same sums
        columns = variables[:, chunk]  # not C-contiguous: the kernel takes a copy
        w = None if weight is None else weight[chunk]
        moments.add(fast, columns, w, fast=True)
        moments.add(slow, columns, w, fast=False)
    assert relative(moments.values(fast), moments.values(slow)) <= SUMS_RTOL


@needs_numba
@pytest.mark.parametrize("reference", [None, PAPER_FIELD, "series"])
def test_a_pass_with_the_compiled_kernel_gives_the_gram_of_the_numpy_pass(reference, monkeypatch):
    samples, _ = make_log(n=7000, noise=2.0, seed=13)
    if reference == "series":
        reference = PAPER_FIELD * (1.0 + 2e-3 * np.sin(np.linspace(0.0, 20.0, len(samples))))
    monkeypatch.setenv(compiled.KERNEL_VARIABLE, "numpy")
    slow = accumulate(samples, reference)
    monkeypatch.setenv(compiled.KERNEL_VARIABLE, "numba")
    fast = accumulate(samples, reference)
    assert relative(fast.gram, slow.gram) <= SUMS_RTOL
    assert fast.measured == slow.measured  # the Table 1 sums are numpy's in both


@needs_numba
@pytest.mark.parametrize("loss", [Loss(), Loss("huber", 30.0)])
@pytest.mark.parametrize("reference", [None, PAPER_FIELD])
def test_the_compiled_score_columns_give_the_score_sums_of_numpy(loss, reference, monkeypatch):
    samples, _ = make_log(n=10_007, noise=2.0, seed=23)
    theta = np.array([-71.0, 188.0, 116.0, 0.007, -0.002, -0.005, -0.04, 0.02, -0.005])
    centre = None if reference is not None else 49_460.0  # about the median |B1| at theta
    found = {}
    for kernel in ("numpy", "numba"):
        monkeypatch.setenv(compiled.KERNEL_VARIABLE, kernel)
        # chunks of 4 000 rows: the last one fills the work arrays in part
        found[kernel] = score_block_sums(samples, theta, reference, loss, centre, 49_000.0, 4_000)
    (series, informations, rows, bias, meat), fast = found["numpy"], found["numba"]
    assert fast[2] == rows
    for mine, theirs in [(series, fast[0]), (informations, fast[1]), (meat, fast[4])]:
        assert relative(theirs, mine) <= SUMS_RTOL
    assert relative(fast[3]["gradient"], bias["gradient"]) <= SUMS_RTOL
    assert abs(fast[3]["mean_square_g"] / bias["mean_square_g"] - 1.0) <= SUMS_RTOL


def score_chunk(terms, raw):
    """(|B1|, the work array, y) of `ScoreTerms.add` on one chunk of raw samples."""
    space = terms.workspace(raw.shape[0] + 5)  # arrays longer than the chunk, as for a last one
    part = terms.empty(0, raw.shape[0])
    magnitude, _ = terms.add(part, space, raw, None, 0, 0)
    n = raw.shape[0]
    return magnitude, space[0][:, :n], space[1][:, :n]


@needs_numba
def test_a_sample_at_the_offset_gives_the_same_columns_in_both_kernels():
    # |B1| = 0: numpy's inf and nan, not a ZeroDivisionError from the compiled loop
    terms = score_terms(np.zeros(9), 49_000.0, 8, None, 49_000.0, False)
    raw = np.random.default_rng(2).normal(0.0, 30_000.0, (8, 3))
    raw[3] = terms.offset
    with np.errstate(divide="ignore", invalid="ignore"):
        slow = score_chunk(terms, raw)
        fast = score_chunk(replace(terms, fast=True), raw)
    assert fast[0][3] == 0.0 and np.isinf(fast[1][11, 3])
    for mine, theirs in zip(slow, fast):
        np.testing.assert_allclose(theirs, mine, rtol=1e-12, equal_nan=True)


@needs_numba
def test_a_calibration_with_the_compiled_kernel_is_the_numpy_one(monkeypatch):
    samples, _ = make_log(n=5000, noise=2.0, seed=17)
    results = {}
    for kernel in ("numpy", "numba"):
        monkeypatch.setenv(compiled.KERNEL_VARIABLE, kernel)
        results[kernel] = nlpcal.calibrate(samples, method="joint", reference_field=PAPER_FIELD)
    slow, fast = results["numpy"], results["numba"]
    for name, value in slow.parameters.items():
        # the same optimum: rounding of the moments, far below the Newton steps' resolution
        assert abs(fast.parameters[name] - value) <= 1e-3 * slow.standard_errors[name], name


def test_a_pass_uses_the_compiled_kernel_from_its_threshold_unless_told(monkeypatch):
    monkeypatch.delenv(compiled.KERNEL_VARIABLE, raising=False)
    assert not compiled.use(compiled.COMPILED_FROM - 1)
    assert compiled.use(compiled.COMPILED_FROM) == compiled.available()
    monkeypatch.setenv(compiled.KERNEL_VARIABLE, "numpy")
    assert not compiled.use(10 * compiled.COMPILED_FROM)
    monkeypatch.setenv(compiled.KERNEL_VARIABLE, " Auto ")
    assert not compiled.use(10)
    if compiled.available():
        monkeypatch.setenv(compiled.KERNEL_VARIABLE, "numba")
        assert compiled.use(10)


def test_a_kernel_that_is_not_one_or_numba_missing_is_bad_input(monkeypatch):
    monkeypatch.setenv(compiled.KERNEL_VARIABLE, "fortran")
    with pytest.raises(InputError, match="NLPCAL_KERNEL"):
        compiled.use(10)
    monkeypatch.setattr(compiled, "available", lambda: False)
    monkeypatch.setenv(compiled.KERNEL_VARIABLE, "numba")
    with pytest.raises(InputError, match="nlpcal\\[fast\\]"):
        compiled.use(10)
    monkeypatch.setenv(compiled.KERNEL_VARIABLE, "auto")
    assert not compiled.use(10 * compiled.COMPILED_FROM)  # auto without numba: numpy


def test_numba_that_cannot_keep_its_cache_is_said_or_passed_over(monkeypatch):
    # numba raises RuntimeError on import where no folder for its cache is writable (a
    # read-only install and a HOME it may not write): asked for, a refusal that says what to
    # do; in "auto", the numpy kernel.
    why = "numba cannot keep the compiled kernel (no locator); set NUMBA_CACHE_DIR to a folder"
    monkeypatch.setattr(compiled, "available", lambda: True)
    monkeypatch.setattr(compiled, "_imported", lambda: (None, why))
    monkeypatch.setenv(compiled.KERNEL_VARIABLE, "numba")
    with pytest.raises(InputError, match="NUMBA_CACHE_DIR"):
        compiled.use(10)
    with pytest.raises(InputError, match="NUMBA_CACHE_DIR"):
        compiled.load()
    monkeypatch.setenv(compiled.KERNEL_VARIABLE, "auto")
    assert not compiled.use(10 * compiled.COMPILED_FROM)


def test_the_command_line_refuses_an_unknown_kernel_with_exit_2(monkeypatch, capsys, tmp_path):
    monkeypatch.setenv(compiled.KERNEL_VARIABLE, "fortran")
    output = tmp_path / "params.json"
    code = main(["calibrate", str(EXAMPLE), "-o", str(output)])
    err = capsys.readouterr().err
    assert code == 2
    assert "NLPCAL_KERNEL" in err and "Traceback" not in err
    assert not output.exists()
    # before anything is read, for every command: a batch marks no log as bad
    code = main(["batch", "calibrate", str(EXAMPLE), "--out-dir", str(tmp_path / "out")])
    assert code == 2 and "NLPCAL_KERNEL" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()


@needs_numba  # (without it, nothing could load it)
def test_a_short_log_does_not_load_numba(tmp_path):
    """Below COMPILED_FROM samples the numpy kernel runs: numba, which takes 0.3-0.45 s to load,
    is not even imported."""
    code = (
        "import sys\n"
        "from nlpcal.cli import main\n"
        f"code = main(['calibrate', {str(EXAMPLE)!r}, '-o', {str(tmp_path / 'p.json')!r}])\n"
        "print(code, 'numba' in sys.modules)\n"
    )
    env = {k: v for k, v in os.environ.items() if k != compiled.KERNEL_VARIABLE}
    done = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=120, env=env
    )
    assert done.stdout.splitlines()[-1] == "0 False", done.stderr


@needs_numba
@pytest.mark.slow  # a local cluster of two processes, seconds
def test_dask_worker_processes_run_the_compiled_kernel_to_the_same_result(monkeypatch):
    distributed = pytest.importorskip("distributed")
    da = pytest.importorskip("dask.array")
    samples, _ = make_log(n=20_000, noise=2.0, seed=19)
    monkeypatch.setenv(compiled.KERNEL_VARIABLE, "numpy")
    memory = nlpcal.calibrate(samples, method="joint", reference_field=PAPER_FIELD)
    monkeypatch.setenv(compiled.KERNEL_VARIABLE, "numba")
    with (
        distributed.LocalCluster(
            n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None
        ) as cluster,
        distributed.Client(cluster) as client,
    ):
        lazy = nlpcal.calibrate(
            da.from_array(samples, chunks=(6_000, 3)), method="joint", reference_field=PAPER_FIELD
        )
        loaded = client.run(
            lambda: {"nlpcal._moment_kernel", "nlpcal._score_kernel"} <= set(sys.modules)
        )
    assert all(loaded.values()) and len(loaded) == 2  # each worker ran them
    for name, value in memory.parameters.items():
        assert abs(lazy.parameters[name] - value) <= 1e-3 * memory.standard_errors[name], name


def test_a_pass_told_to_run_the_compiled_kernel_without_numba_runs_numpy(monkeypatch):
    # a Dask worker without the fast extra, under a driver that has it
    moments = gram_moments(False)
    variables = np.random.default_rng(3).normal(0.0, 0.5, (5, 500))
    expected = moments.empty()
    moments.add(expected, variables)
    monkeypatch.setattr(compiled, "_imported", lambda: (None, "numba cannot be imported"))
    found = moments.empty()
    moments.add(found, variables, fast=True)
    np.testing.assert_array_equal(found, expected)
    terms = score_terms(np.zeros(9), 1.0, 500, None, 1.0, False)
    raw = variables[:3].T
    expected = score_chunk(terms, raw)
    found = score_chunk(replace(terms, fast=True), raw)
    for mine, theirs in zip(expected, found):
        np.testing.assert_array_equal(theirs, mine)
