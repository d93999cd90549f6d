"""One log on Dask: the same calibration as in memory, every pass a reduction over blocks.

The tolerances: the Dask pass adds the same numbers in another order (per block, then a tree),
which changes the Gram matrix by rounding (1e-12 relative, checked below). The solvers turn that
into differences of their own stopping tolerance, exactly as running in memory on one core instead
of two does (docs/scale.md measures both): parameters within 0.02 standard errors, the resolution
every block solve promises (`resolution.SAME_OPTIMUM_SE`), Table 1 rows within 1e-6 relative;
the same number of cycles, the same coverage, identifiability and warnings. The scores' block
sums at one theta do not depend on how the rows are split (1e-9, checked below); the standard
errors, taken at parameters 0.02 standard errors apart, differ by what that moves them:
ERROR_TOLERANCE.
"""

import contextlib
import json
import logging
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pandas as pd
import pytest

import nlpcal
from nlpcal import passes
from nlpcal.calibration import scores
from nlpcal.cli import main
from nlpcal.moments import accumulate
from nlpcal.nlp.solver import builds
from nlpcal.robust import Loss
from resolution import SAME_OPTIMUM_SE, assert_same_optimum
from synthetic import PAPER_FIELD, make_log

dask = pytest.importorskip("dask")
da = pytest.importorskip("dask.array")

ROW_TOLERANCE = 1e-6
#: Parameters 0.02 SE apart move s^2 A^-1 (independent samples: these logs) by about 1e-4
#: relative, and the jackknife of dependent scores by up to 5 % (its group length can change
#: by one block besides).
ERROR_TOLERANCE = {"independent": 1e-3, "block-jackknife": 0.05}
#: A least-squares fit on Dask is the in-memory one within these many standard errors (joint:
#: the Newton steps that finish it; staged: its cycles' rtol rule).
DASK_SE = {"joint": 1e-3, "staged": 1e-2}


@pytest.fixture(scope="module")
def spiky_log():
    samples, _ = make_log(n=40_000, noise=1.0, seed=71)
    samples[::397] += 60.0  # spikes for the robust loss
    return samples


def largest_gap(lazy, memory) -> float:
    """The largest difference of the parameters, in the in-memory result's standard errors."""
    errors = memory.standard_errors or memory.identifiability["standard_errors_at_joint_optimum"]
    return max(abs(lazy.parameters[k] - v) / errors[k] for k, v in memory.parameters.items())


def assert_same_calibration(memory, lazy):
    errors = memory.standard_errors or memory.identifiability["standard_errors_at_joint_optimum"]
    for name, value in memory.parameters.items():
        gap = abs(lazy.parameters[name] - value) / errors[name]
        assert gap <= SAME_OPTIMUM_SE, (name, gap)  # the same cycles: each block solve's too
    assert len(lazy.statistics) == len(memory.statistics)
    for row, again in zip(memory.statistics, lazy.statistics):
        assert again.get("from_moments") == row.get("from_moments")
        for key in ("max", "min", "mean", "std", "range", "objective"):
            if row[key] is None:  # a row from the moments has no max, min or range
                assert again[key] is None
            else:
                assert again[key] == pytest.approx(row[key], rel=ROW_TOLERANCE, abs=1e-9), key
    if memory.standard_errors is not None:
        method = memory.identifiability["score_dependence"]["method"]
        assert lazy.identifiability["score_dependence"]["method"] == method
        for name, value in memory.standard_errors.items():
            assert lazy.standard_errors[name] == pytest.approx(value, rel=ERROR_TOLERANCE[method])
    for key in ("coverage", "not_identifiable", "poorly_determined", "weakest_combination"):
        assert lazy.identifiability[key] == memory.identifiability[key], key
    assert lazy.warnings == memory.warnings
    assert lazy.reference == pytest.approx(memory.reference)
    assert lazy.n_samples == memory.n_samples


@pytest.mark.parametrize(
    "method, reference, loss",
    [
        ("staged", None, "l2"),
        ("joint", None, "l2"),
        ("staged", "constant", "huber"),
        ("joint", "series", "l2"),
        ("joint", "series", "cauchy"),
    ],
)
def test_a_dask_array_calibrates_as_the_same_array_in_memory(spiky_log, method, reference, loss):
    n = spiky_log.shape[0]
    ramp = PAPER_FIELD + 3.0 * np.sin(np.arange(n) / 500.0)
    samples = spiky_log * (ramp / PAPER_FIELD)[:, None] if reference == "series" else spiky_log
    field = {None: None, "constant": PAPER_FIELD, "series": ramp}[reference]
    memory = nlpcal.calibrate(samples, method=method, reference_field=field, loss=loss)
    lazy_field = da.from_array(ramp, chunks=6_100) if reference == "series" else field
    with dask.config.set(scheduler="threads"):
        lazy = nlpcal.calibrate(
            da.from_array(samples, chunks=(6_100, 3)),  # blocks unlike the in-memory shares
            method=method,
            reference_field=lazy_field,
            loss=loss,
        )
    assert_same_calibration(memory, lazy)


def test_the_gram_matrix_differs_by_rounding_only_and_no_block_is_loaded_whole(spiky_log):
    memory = accumulate(spiky_log, PAPER_FIELD)
    lazy = passes.LazySamples(da.from_array(spiky_log, chunks=(5_000, 3)))
    with dask.config.set(scheduler="sync"):
        again = accumulate(lazy, PAPER_FIELD)
    scale = np.abs(memory.gram).max()
    assert np.abs(again.gram - memory.gram).max() < 1e-12 * scale
    assert again.measured == pytest.approx(memory.measured, rel=1e-12)
    np.testing.assert_array_equal(again.frame.centre, memory.frame.centre)  # same subsample
    assert lazy.passes == 2  # the survey, then the Gram pass
    with pytest.raises(TypeError, match="not turned into one numpy array"):
        np.asarray(lazy)


def counted_calibration(samples, **options) -> tuple:
    """(LazySamples, result, the names of the works of its passes after the survey) of a
    calibration of `samples` as a Dask log in blocks of 10 000 rows."""
    works = []
    original = passes._reduce_dask

    def counting(values, reference, work, *args):
        works.append(type(work).__name__)
        return original(values, reference, work, *args)

    passes._reduce_dask = counting
    try:
        with dask.config.set(scheduler="sync"):
            lazy = passes.LazySamples(da.from_array(samples, chunks=(10_000, 3)))
            result = nlpcal.calibrate(lazy, **options)
    finally:
        passes._reduce_dask = original
    return lazy, result, works


@pytest.mark.parametrize("method", ["staged", "joint"])
@pytest.mark.parametrize("reference", [None, "constant", "series"])
def test_a_least_squares_calibration_on_dask_reads_the_blocks_in_two_passes(
    spiky_log, method, reference
):
    """The moments, then one pass after the solve for every exact Table 1 row (each at its own
    cycle's parameters) and the scores; the subsamples of the diagnostics (frame, coverage,
    residual spread) come from the survey, which the first pass gathers on the way (its frame
    fitted to the first block, read apart, and kept, being near the frame of the samples in
    memory). The result
    is the in-memory one within DASK_SE standard errors (the Gram matrix differs by rounding,
    which the solvers' Newton steps resolve far below their 0.01 SE; 1e-6 SE measured) and its
    standard errors within 1e-3 (1e-11 measured: the same scores at the same parameters)."""
    n = spiky_log.shape[0]
    field = {None: None, "constant": PAPER_FIELD, "series": np.full(n, PAPER_FIELD)}[reference]
    lazy, result, works = counted_calibration(spiky_log, method=method, reference_field=field)
    exact = [row for row in result.statistics[1:] if not row.get("from_moments")]
    assert len(exact) >= 2 if method == "staged" else len(exact) == 1
    assert all(row.max is not None and row.series_rel_error is not None for row in exact)
    names = [what for what, _ in lazy.timings]
    assert names == ["head", "MomentBlock + survey", "AfterSolve"] and lazy.passes == 2
    assert works == ["MomentBlock", "AfterSolve"]
    memory = nlpcal.calibrate(spiky_log, method=method, reference_field=field)
    errors = memory.standard_errors
    assert errors is not None and result.standard_errors is not None
    for name, value in memory.parameters.items():
        assert abs(result.parameters[name] - value) <= DASK_SE[method] * errors[name], name
        assert result.standard_errors[name] == pytest.approx(errors[name], rel=1e-3), name
    for row, again in zip(memory.statistics, result.statistics):
        for key in ("max", "min", "mean", "std", "range", "objective"):
            if row[key] is None:  # a row from the moments
                assert again[key] is None
            else:
                assert again[key] == pytest.approx(row[key], rel=ROW_TOLERANCE), key


def test_a_robust_joint_fit_on_dask_reads_the_blocks_once_after_its_last_reweighting(spiky_log):
    """After the last reweighting's moments, one pass: the joint row with the loss's sums and
    the exact objective its weights expand, the scores with the bread of the sandwich, and the
    18 exact objectives of the exact-optimum check."""
    _, result, works = counted_calibration(
        spiky_log, method="joint", reference_field=PAPER_FIELD, loss="huber"
    )
    last = max(k for k, what in enumerate(works) if what == "MomentBlock")
    assert works[last + 1 :] == ["AfterSolve"]
    assert works.count("MomentBlock") == 1 + result.robust["reweightings"]
    row = result.statistics[-1]
    assert row.robust_objective is not None and row.series_rel_error is not None
    assert result.identifiability["exact_optimum_shift_in_standard_errors"] < 0.1


@pytest.mark.parametrize("method", ["joint", "staged"])
def test_least_squares_on_a_parquet_log_reads_it_twice(parquet_log, method):
    from nlpcal.calibration import calibrate_log
    from nlpcal.io import read_log
    from nlpcal.io.lazy import read_lazy_log

    pattern = str(parquet_log / "*.parquet")
    with dask.config.set(scheduler="threads"):
        log = read_lazy_log(pattern)
        result = calibrate_log(log, method=method)
    whole = read_log(parquet_log / "whole.csv")
    memory = calibrate_log(whole, method=method)
    assert_same_calibration(memory, result)
    # the moments with the survey and the reader's checks, then the Table 1 row and the scores
    assert log.samples.passes == 2, log.samples.timings


def test_a_first_block_at_rest_costs_a_pass_in_the_final_frame(spiky_log):
    samples = spiky_log.copy()
    rng = np.random.default_rng(3)
    samples[:6_000] = samples[0] + rng.normal(0.0, 1.0, (6_000, 3))  # the sensor at rest
    memory = nlpcal.calibrate(samples, method="joint")
    with dask.config.set(scheduler="sync"):
        lazy = passes.LazySamples(da.from_array(samples, chunks=(6_000, 3)))
        result = nlpcal.calibrate(lazy, method="joint")
    # the sphere of one attitude is nowhere near the log's: the first pass's moments are not
    # re-centred from it, but gathered again in the final frame
    names = [what for what, _ in lazy.timings]
    assert names[1:3] == ["MomentBlock + survey", "MomentBlock"]
    assert largest_gap(result, memory) <= DASK_SE["joint"]


def test_the_first_frame_near_the_final_one_is_kept_not_moved_by_the_algebra(
    spiky_log, monkeypatch
):
    """Moving the first pass's moments to another centre (M4) turns the rounding of their
    summation order into errors of 1e-12-1e-10 in the small a^k entries, which moved a joint fit
    of 10^7 samples by 8e-3 standard errors between two cluster layouts; so a first frame near
    the final one is kept, and the moments the solves read are exactly the first pass's."""
    from nlpcal.calibration import steps

    kept = []
    original = steps.reframed

    def spy(moments, frame, samples, reference):
        result = original(moments, frame, samples, reference)
        kept.append((moments, result))
        return result

    monkeypatch.setattr(steps, "reframed", spy)
    _, result, works = counted_calibration(spiky_log, method="joint")
    ((first, used),) = kept
    assert used is first and works == ["MomentBlock", "AfterSolve"]
    memory = nlpcal.calibrate(spiky_log, method="joint")
    assert largest_gap(result, memory) <= DASK_SE["joint"]


def test_a_dask_dataframe_has_its_field_columns_detected(spiky_log):
    dd = pytest.importorskip("dask.dataframe")
    frame = pd.DataFrame(spiky_log[:, [2, 0, 1]], columns=["mag_z", "mag_x", "mag_y"])
    frame.insert(0, "time_s", np.arange(len(frame)) * 0.01)
    frame["temp_c"] = 21.0
    memory = nlpcal.calibrate(spiky_log, method="joint")
    with dask.config.set(scheduler="threads"):
        lazy = nlpcal.calibrate(dd.from_pandas(frame, npartitions=4), method="joint")
        pandas = nlpcal.calibrate(frame, method="joint")
    assert_same_calibration(memory, lazy)
    assert_same_optimum(pandas.parameters, memory.parameters, memory.standard_errors)


def test_a_bad_value_in_a_dask_log_is_refused_like_in_memory(spiky_log):
    samples = spiky_log.copy()
    samples[12_345, 1] = np.nan
    reference = np.full(len(samples), PAPER_FIELD)
    reference[99] = -1.0
    for values in (samples, da.from_array(samples, chunks=(7_000, 3))):
        with pytest.raises(nlpcal.InputError, match="NaN or infinite"):
            nlpcal.calibrate(values)
    with pytest.raises(nlpcal.InputError, match="1 non-positive"):
        nlpcal.calibrate(spiky_log, reference_field=da.from_array(reference, chunks=5_000))


@pytest.fixture(scope="module")
def cluster():
    distributed = pytest.importorskip("distributed")
    with distributed.LocalCluster(
        n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None
    ) as local:
        yield local


@pytest.fixture(scope="module")
def parquet_log(tmp_path_factory, spiky_log):
    pytest.importorskip("pyarrow")
    folder = tmp_path_factory.mktemp("parquet")
    frame = pd.DataFrame(spiky_log, columns=["bx", "by", "bz"])
    frame["proton_nT"] = PAPER_FIELD
    for k, rows in enumerate(np.array_split(np.arange(len(frame)), 3)):
        frame.iloc[rows].to_parquet(folder / f"part{k}.parquet", index=False, row_group_size=5_000)
    frame.to_csv(folder / "whole.csv", index=False)
    return folder


def run(capsys, *argv):
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


@pytest.mark.slow  # end to end, seconds
def test_calibrate_parquet_files_on_a_cluster_as_in_memory(parquet_log, cluster, tmp_path, capsys):
    memory, lazy = tmp_path / "memory.json", tmp_path / "cluster.json"
    options = ["--reference-column", "proton_nT", "--method", "joint"]
    code, _, _ = run(capsys, "calibrate", parquet_log / "whole.csv", *options, "-o", memory)
    assert code == 0
    pattern = str(parquet_log / "*.parquet")
    argv = ["calibrate", pattern, *options, "--scheduler", cluster.scheduler_address]
    code, out, err = run(capsys, *argv, "-o", lazy)
    assert code == 0 and out == "", err
    assert "9 Parquet row groups are read once and kept in memory" in err
    assert "on the workers of the Dask cluster at tcp://" in err
    first, second = (nlpcal.CalibrationResult.load(path) for path in (memory, lazy))
    assert_same_calibration(first, second)
    assert second.input["log"] == pattern and second.reference.column == "proton_nT"


def test_calibrate_on_dask_refuses_what_needs_the_log_in_memory(parquet_log, capsys):
    pattern = parquet_log / "*.parquet"
    for extra in (
        ["--plot", "x.png"],
        ["--temperature-column", "proton_nT", "--reference-field", "1"],
    ):
        code, out, err = run(capsys, "calibrate", pattern, "--scheduler", "threads", *extra)
        assert code == 2 and out == "" and len(err.splitlines()) == 1, err


def test_low_memory_on_dask_leaves_the_log_in_its_files(parquet_log, tmp_path, capsys):
    pattern = parquet_log / "*.parquet"
    options = ["--reference-column", "proton_nT", "--method", "joint", "--scheduler", "threads"]
    outputs = {}
    for extra in ([], ["--low-memory"]):
        outputs[bool(extra)] = tmp_path / f"{bool(extra)}.json"
        code, _, err = run(
            capsys, "calibrate", pattern, *options, *extra, "-o", outputs[bool(extra)]
        )
        kept = "9 Parquet row groups are read once and kept in memory" in err
        assert code == 0 and kept == (not extra), err
        assert ("9 Parquet row groups read in every pass" in err) == bool(extra), err
    first, second = (nlpcal.CalibrationResult.load(path) for path in outputs.values())
    assert_same_calibration(first, second)


def test_an_unknown_scheduler_address_is_bad_input(parquet_log, capsys, monkeypatch):
    pytest.importorskip("distributed")
    monkeypatch.setattr(nlpcal.cluster, "CONNECT_TIMEOUT_S", 1)
    code, out, err = run(
        capsys, "calibrate", parquet_log / "whole.csv", "--scheduler", "tcp://127.0.0.1:9"
    )
    assert code == 2 and "no Dask scheduler answers" in err and len(err.splitlines()) == 1


def test_a_scheduler_that_is_no_name_or_address_is_refused_at_once(parquet_log, capsys):
    """A misspelt name is not tried as an address (whose failed Client held the exit for a
    minute, with a traceback); a port nobody listens on is told without a Client; a machine's
    worth of workers is refused before one starts."""
    pytest.importorskip("distributed")
    from nlpcal import chunks

    log = parquet_log / "whole.csv"
    cores = chunks.available_cores()
    for argv, said in (
        (("--scheduler", "Local"), "did you mean 'local'?"),
        (("--scheduler", "PROCESSES"), "did you mean 'processes'?"),
        (("--scheduler", "inproc://somewhere"), "nor a scheduler's address"),
        (("--scheduler", ""), "nor a scheduler's address"),
        (("--scheduler", "127.0.0.1:1"), "no Dask scheduler answers"),  # refused
        (("--scheduler", "local", "--workers", str(4 * cores + 1)), f"at most {4 * cores}"),
        (("--scheduler", "processes", "--workers", "10" * 10), f"at most {4 * cores}"),
    ):
        code, out, err = run(capsys, "calibrate", log, *argv)
        assert code == 2 and out == "" and said in err and len(err.splitlines()) == 1, err


def test_options_that_need_the_log_in_memory_are_refused_before_a_cluster_starts(
    parquet_log, capsys, monkeypatch
):
    def no_cluster(*args, **kwargs):
        raise AssertionError("a cluster started for a refused command")

    monkeypatch.setattr(nlpcal.cluster, "scheduler", no_cluster)
    log = parquet_log / "whole.csv"
    for option in (["--plot", "p.png"], ["--lag", "auto"], ["--aux-columns", "proton_nT"]):
        code, out, err = run(capsys, "calibrate", log, "--scheduler", "local", *option)
        assert code == 2 and out == "" and option[0] in err and len(err.splitlines()) == 1


def test_a_fleet_on_a_cluster_matches_the_fleet_in_this_process(tmp_path, cluster, capsys):
    fleet = tmp_path / "fleet"
    fleet.mkdir()
    for k in range(4):
        samples, _ = make_log(n=1500, noise=1.0, seed=200 + k)
        pd.DataFrame(samples, columns=["bx", "by", "bz"]).to_csv(fleet / f"s{k}.csv", index=False)
    (fleet / "broken.csv").write_text("bx,by,bz\n1,2,three\n")
    summaries = {}
    for name, extra in (("here", []), ("cluster", ["--scheduler", cluster.scheduler_address])):
        out_dir = tmp_path / name
        code, out, err = run(
            capsys, "batch", "calibrate", fleet, "--out-dir", out_dir, "--method", "joint", *extra
        )
        assert code == 2 and out == "" and "Traceback" not in err
        summaries[name] = pd.read_csv(out_dir / "summary.csv")
    here, there = summaries["here"], summaries["cluster"]
    assert list(there["status"]) == ["bad-input", "ok", "ok", "ok", "ok"]
    gaps = (there["z_x"] - here["z_x"]).abs() / here["z_x_se"]
    assert (gaps.iloc[1:] <= SAME_OPTIMUM_SE).all()
    first = json.loads((tmp_path / "cluster" / "s0.params.json").read_text())
    near = json.loads((tmp_path / "here" / "s0.params.json").read_text())
    assert_same_optimum(first["parameters"], near["parameters"], near["standard_errors"])
    # Each worker process built its problems once: a second fleet builds nothing more.
    client = pytest.importorskip("distributed").Client(cluster)
    built = client.run(builds)
    argv = ["batch", "calibrate", fleet, "--out-dir", tmp_path / "cluster", "--method", "joint"]
    run(capsys, *argv, "--force", "--scheduler", cluster.scheduler_address)
    # (a joint fit builds six: the coefficients of u and their derivatives, the objective of the
    # moments with and without its derivatives, the objective of theta with them and without)
    assert client.run(builds) == built and max(built.values()) <= 6
    client.close()


def test_csv_in_blocks_reads_like_read_log(tmp_path, spiky_log):
    from nlpcal.io import read_log
    from nlpcal.io.lazy import read_lazy_log

    frame = pd.DataFrame(spiky_log[:5000] / 1000.0, columns=["mx_uT", "my_uT", "mz_uT"])
    frame["proton_nT"] = PAPER_FIELD
    frame.loc[1234, "my_uT"] = np.nan  # dropped with drop_invalid, in one of the blocks
    for k, rows in enumerate(np.array_split(np.arange(len(frame)), 2)):
        frame.iloc[rows].to_csv(tmp_path / f"log_{k}.csv", index=False)
    pattern = tmp_path / "log_*.csv"
    options = {"reference_column": "proton_nT", "drop_invalid": True}
    memory = read_log(pattern, **options)
    with dask.config.set(scheduler="threads"):
        lazy = read_lazy_log(pattern, block_bytes=20_000, **options)  # about 20 blocks
        assert len(lazy.samples.block_offsets()) > 10
        np.testing.assert_array_equal(lazy.samples[::1], memory.samples)
        np.testing.assert_array_equal(lazy.reference[::1], memory.reference)
    assert lazy.unit == "uT" and lazy.dropped == memory.dropped == 1
    assert "dropped 1 row(s)" in " ".join(lazy.notes)
    with dask.config.set(scheduler="threads"), pytest.raises(nlpcal.InputError, match="my_uT"):
        read_lazy_log(pattern, block_bytes=20_000, reference_column="proton_nT")


def test_a_scheduler_that_cannot_start_is_bad_usage_at_once(tmp_path, capsys):
    samples, _ = make_log(n=300, noise=1.0, seed=3)
    path = tmp_path / "log.csv"
    pd.DataFrame(samples, columns=["bx", "by", "bz"]).to_csv(path, index=False)
    missing = tmp_path / "no" / "scheduler.json"  # dask.distributed would wait for it forever
    for argv in (
        ("--scheduler", missing),
        ("--scheduler", "local", "--workers", "0"),
        ("--scheduler", "processes", "--workers", "-1"),
    ):
        code, out, err = run(capsys, "calibrate", path, *argv)
        assert code == 2 and out == "" and "Traceback" not in err, (argv, err)
    code, _, err = run(capsys, "calibrate", path, "--workers", "2", "--method", "joint")
    assert code == 0 and "--workers only sizes --scheduler" in err


def test_the_exact_objective_at_many_points_takes_one_pass(spiky_log):
    from nlpcal.statistics import exact_objectives, field_statistics

    rng = np.random.default_rng(4)
    truth = np.array([-71.55, 188.13, 116.29, 0.0072, -0.0024, -0.0049, -0.0408, 0.0225, -0.0047])
    thetas = [truth + rng.normal(0.0, [1.0] * 3 + [1e-4] * 3 + [1e-4] * 3) for _ in range(18)]
    for reference in (None, PAPER_FIELD, np.full(len(spiky_log), PAPER_FIELD)):
        expected = [field_statistics(spiky_log, t, reference)["objective"] for t in thetas]
        np.testing.assert_allclose(exact_objectives(spiky_log, thetas, reference), expected)
        with dask.config.set(scheduler="sync"):
            lazy = passes.LazySamples(da.from_array(spiky_log, chunks=(7_000, 3)))
            lazy.survey()
            before = lazy.passes
            values = exact_objectives(lazy, thetas, reference)
        assert lazy.passes == before + 1
        np.testing.assert_allclose(values, expected, rtol=1e-9)


@pytest.mark.parametrize("keep", [False, True])
def test_a_bad_value_on_dask_is_placed_as_the_reader_in_memory_places_it(tmp_path, keep):
    pytest.importorskip("pyarrow")
    from nlpcal.calibration import calibrate_log
    from nlpcal.errors import InputError
    from nlpcal.io import read_log
    from nlpcal.io.lazy import read_lazy_log

    samples, _ = make_log(n=30_000, noise=1.0, seed=5)
    frame = pd.DataFrame(samples, columns=["bx", "by", "bz"])
    frame.loc[23_456, "by"] = np.nan
    parquet = tmp_path / "log.parquet"
    frame.to_parquet(parquet, index=False, row_group_size=10_000)
    text = tmp_path / "log.csv"
    frame.to_csv(text, index=False)
    with pytest.raises(InputError) as memory:
        read_log(parquet)
    assert "data row 23457" in str(memory.value)
    with dask.config.set(scheduler="sync"):
        if keep:  # read whole when opened, to be kept in memory
            with pytest.raises(InputError) as lazy:
                read_lazy_log(parquet)
        else:  # no pass: the blocks are checked in the first one
            log = read_lazy_log(parquet, keep=False)
            with pytest.raises(InputError) as lazy:
                calibrate_log(log)
        assert "data row 23457" in str(lazy.value)
        with pytest.raises(InputError) as blocks:
            read_lazy_log(text, block_bytes=100_000, keep=keep)
    message = str(blocks.value)
    assert "counted from its start" in message and "data row 23457" not in message


def test_a_refused_value_on_a_local_cluster_is_one_line_of_stderr(tmp_path):
    """The workers of --scheduler local log their tasks' failures on the terminal: a value the
    reader refused is said once, by nlpcal, without dask.distributed's worker traceback."""
    pytest.importorskip("distributed")
    pytest.importorskip("pyarrow")
    samples, _ = make_log(n=30_000, noise=1.0, seed=5)
    frame = pd.DataFrame(samples, columns=["bx", "by", "bz"])
    frame.loc[23_456, "by"] = np.nan
    frame.to_parquet(tmp_path / "log.parquet", index=False, row_group_size=10_000)
    argv = ["calibrate", "log.parquet", "--scheduler", "local", "--workers", "2", "-o", "p.json"]
    for extra in ([], ["--low-memory"]):  # read when opened, or in the first pass
        done = subprocess.run(
            [sys.executable, "-m", "nlpcal", *argv, *extra],
            cwd=tmp_path,
            capture_output=True,
            text=True,
            timeout=300,
        )
        errors = [line for line in done.stderr.splitlines() if "error" in line.lower()]
        assert done.returncode == 2 and done.stdout == "", done.stderr
        assert len(errors) == 1 and "data row 23457" in errors[0], done.stderr
        assert errors[0].startswith("nlpcal calibrate: error: "), done.stderr
        assert "Traceback" not in done.stderr and "Compute Failed" not in done.stderr
        assert not (tmp_path / "p.json").exists()


def test_a_worker_log_keeps_every_failure_but_a_refused_value():
    from nlpcal.cluster import refusal_unlogged

    def record(exception: str):
        text = "Compute Failed\nKey: %s\nException: %r\n"
        return logging.LogRecord(
            "distributed.worker", logging.ERROR, "", 0, text, ("k", exception), None
        )

    assert not refusal_unlogged(record("InputError('log.parquet: 1 row(s) have a missing value')"))
    assert refusal_unlogged(record("MemoryError()"))
    assert refusal_unlogged(record("ZeroDivisionError('float division by zero')"))
    other = logging.LogRecord("distributed.worker", logging.WARNING, "", 0, "InputError(", (), None)
    assert refusal_unlogged(other)


def test_a_worker_log_leaves_out_only_what_a_closing_cluster_brings():
    """What a worker meets as nlpcal closes its cluster midway (an interruption, which nlpcal
    states itself) is left out; anything else a worker logs stays."""
    from nlpcal.cluster import closing_unlogged

    def record(text: str, *args):
        return logging.LogRecord("distributed.worker", logging.ERROR, "", 0, text, args, None)

    assert not closing_unlogged(record("Failed to communicate with scheduler during heartbeat."))
    cancelled = record("Async instruction for %s ended with CancelledError", "<Task execute>")
    assert not closing_unlogged(cancelled)
    assert closing_unlogged(record("Unexpected exception during heartbeat. Closing worker."))
    assert closing_unlogged(record("Compute Failed\nKey: %s", "k"))


def test_the_first_block_sends_only_the_rows_its_sphere_fit_reads():
    """Before the first pass a Dask log's first block gives the frame of its moments and the
    plausibility of its unit: the even stride of it those read, and the leading rows the pass
    shifts its sums by, in one computation; the frame and the magnitudes are those of the whole
    block, bit for bit."""
    from nlpcal.io.logs import typical_magnitudes
    from nlpcal.moments import sphere_frame

    samples, _ = make_log(n=250_000, noise=1.0, seed=7)
    for rows in (100_000, 30_000, 7_000):  # strides 5, 1 (30 000 of 20 000), 1
        with dask.config.set(scheduler="sync"):
            lazy = passes.LazySamples(da.from_array(samples, chunks=(rows, 3)))
            sample = passes.first_block_sample(lazy)
            lead = lazy[: passes.SURVEY_HEAD]
        assert [what for what, _ in lazy.timings] == ["head"]
        block = samples[:rows]
        np.testing.assert_array_equal(sample, block[:: max(1, rows // 20_000)])
        np.testing.assert_array_equal(lead, samples[: passes.SURVEY_HEAD])
        whole, mine = sphere_frame(block), sphere_frame(sample)
        assert whole.radius == mine.radius and np.array_equal(whole.centre, mine.centre)
        assert typical_magnitudes(block) == typical_magnitudes(sample)


def test_a_compressed_text_log_is_read_on_dask_as_in_memory(tmp_path):
    """A compressed text log is one block, decompressed where it is read; cut short, it is
    refused as unreadable input, in memory and on Dask alike."""
    from nlpcal.errors import InputError
    from nlpcal.io import read_log
    from nlpcal.io.lazy import read_lazy_log

    samples, _ = make_log(n=100_000, noise=1.0, seed=8)
    path = tmp_path / "log.csv.gz"
    pd.DataFrame(samples, columns=["bx", "by", "bz"]).to_csv(path, index=False)
    memory = read_log(path)
    with dask.config.set(scheduler="threads"):
        lazy = read_lazy_log(path)
        np.testing.assert_array_equal(lazy.samples[::1], memory.samples)
    whole = path.read_bytes()
    damaged = bytearray(whole)
    damaged[5_000:5_400] = bytes(400)
    for name, content in (
        ("cut early", whole[:20_000]),  # within the head read to detect the layout
        ("cut late", whole[: len(whole) * 4 // 5]),
        ("damaged", bytes(damaged)),
    ):
        bad = tmp_path / f"{name}.csv.gz"
        bad.write_bytes(content)
        for low_memory in (False, True):
            with pytest.raises(InputError, match="cannot be read"):
                read_log(bad, low_memory=low_memory)
        with dask.config.set(scheduler="threads"), pytest.raises(InputError, match="cannot be"):
            read_lazy_log(bad, keep=False).samples.survey()


@pytest.mark.parametrize("keep", [False, True])
def test_values_out_of_range_on_dask_are_refused_as_in_memory_and_quietly(tmp_path, keep):
    """A reference of zeros, samples of 1e-300 or of 1e300: refused by the checks that refuse
    them in memory (they ended in ZeroDivisionError on Dask), without a floating-point warning
    from the arithmetic on them that comes before those checks on Dask."""
    import warnings

    pytest.importorskip("pyarrow")
    from nlpcal.calibration import calibrate_log
    from nlpcal.errors import InputError
    from nlpcal.io import read_log
    from nlpcal.io.lazy import read_lazy_log

    samples, _ = make_log(n=3_000, noise=1.0, seed=6)
    cases = {
        "zeros": (samples, np.zeros(len(samples)), "non-positive"),
        "one zero": (samples, np.r_[PAPER_FIELD * np.ones(len(samples) - 1), 0.0], "non-positive"),
        "tiny": (samples * 1e-300, None, "below 1e-09"),
        "huge": (samples * 1e300, None, r"beyond 1e\+12"),
    }
    for name, (values, reference, said) in cases.items():
        frame = pd.DataFrame(values, columns=["bx", "by", "bz"])
        if reference is not None:
            frame["proton_nT"] = reference
        path = tmp_path / f"{name}.parquet"
        frame.to_parquet(path, index=False, row_group_size=1_000)
        options = {"reference_column": "proton_nT"} if reference is not None else {}
        with pytest.raises(InputError, match=said):
            calibrate_log(read_log(path, **options))
        with warnings.catch_warnings(), dask.config.set(scheduler="sync"):
            warnings.simplefilter("error", RuntimeWarning)
            with pytest.raises(InputError, match=said):
                calibrate_log(read_lazy_log(path, keep=keep, **options))


def test_a_unit_warning_names_the_size_of_values_of_any_size(tmp_path):
    """The magnitude a unit warning on a Dask log's first block names, of values whose squares
    leave float64 too (it said "about 1.00 nT" of 5e-296 nT), in a few figures (not 300
    digits)."""
    from nlpcal.io import read_log
    from nlpcal.io.lazy import read_lazy_log
    from nlpcal.units import readable

    assert [readable(v) for v in (49_462.0, 0.5, 3e-296, 5e15)] == [
        "49 500",
        "0.500",
        "3e-296",
        "5e+15",
    ]
    samples, _ = make_log(n=2_000, noise=1.0, seed=2)
    for factor, said in ((1e-300, "about 4.95e-296 nT"), (1e300, "about 4.95e+304 nT")):
        path = tmp_path / "log.csv"
        pd.DataFrame(samples * factor, columns=["bx", "by", "bz"]).to_csv(path, index=False)
        with pytest.raises(nlpcal.InputError, match="in any unit"):  # checked as it is read
            read_log(path)
        with dask.config.set(scheduler="sync"):  # checked in the first pass
            assert said in read_lazy_log(path).warnings[0]


def test_a_parquet_log_with_two_columns_of_one_name_reads_as_its_csv(tmp_path):
    """A repeated column name is numbered as pandas numbers it in a CSV header (bx, bx.1): in
    memory, chunk by chunk and on Dask the log reads as its CSV copy does (it ended in an
    internal error); a log from stdin is refused on Dask."""
    pa = pytest.importorskip("pyarrow")
    import pyarrow.parquet as pq

    from nlpcal.errors import InputError
    from nlpcal.io import read_log
    from nlpcal.io.lazy import read_lazy_log

    samples, _ = make_log(n=2_000, noise=1.0, seed=2)
    names = ["bx", "by", "bz", " bx", "temp", "temp"]  # names are read stripped
    columns = [samples[:, 0], samples[:, 1], samples[:, 2], samples[:, 0] + 1.0]
    columns += [np.full(len(samples), 20.0), np.full(len(samples), 21.0)]
    path = tmp_path / "twice.parquet"
    pq.write_table(pa.table([pa.array(c) for c in columns], names=names), path)
    text = tmp_path / "twice.csv"
    pd.DataFrame(np.column_stack(columns)).to_csv(text, header=names, index=False)
    expected = read_log(text, reference_field=PAPER_FIELD)
    for log in (
        read_log(path, reference_field=PAPER_FIELD),
        read_log(path, reference_field=PAPER_FIELD, low_memory=True),
    ):
        np.testing.assert_array_equal(np.asarray(log.samples), expected.samples)
    with dask.config.set(scheduler="sync"):
        lazy = read_lazy_log(path, reference_column="bx.1")
        np.testing.assert_array_equal(lazy.reference[::1], samples[:, 0] + 1.0)
        np.testing.assert_array_equal(lazy.samples[::1], expected.samples)
    with pytest.raises(InputError, match="stdin"):
        read_lazy_log("-")


def test_the_scores_block_sums_do_not_depend_on_how_the_rows_are_split(monkeypatch):
    samples, _ = make_log(n=10_007, noise=1.0, seed=5)
    theta = np.zeros(9)
    theta[0:3] = samples.mean(axis=0)
    monkeypatch.setattr(scores, "MAX_BLOCKS", 97)  # blocks of 104 samples, unaligned to chunks
    options = (theta, None, Loss(), 49_000.0, 49_000.0)
    whole = scores.score_block_sums(samples, *options, chunk_rows=10_007)
    threads = scores.score_block_sums(samples, *options, chunk_rows=333)
    with dask.config.set(scheduler="sync"):
        lazy = passes.LazySamples(da.from_array(samples, chunks=(1_001, 3)))
        spread = scores.score_block_sums(lazy, *options, chunk_rows=333)
    assert whole[2] == threads[2] == spread[2] == 104 and whole[0].shape == (97, 9)
    for other in (threads, spread):
        for mine, theirs in zip(whole[:2] + whole[4:], other[:2] + other[4:]):
            np.testing.assert_allclose(theirs, mine, rtol=1e-9, atol=1e-9 * np.abs(mine).max())


def test_an_assumed_unit_ruled_out_is_raw_counts_in_blocks_too(tmp_path, spiky_log):
    from nlpcal.io import read_log
    from nlpcal.io.lazy import read_lazy_log

    frame = pd.DataFrame(spiky_log[:3000] / 1e5, columns=["bx", "by", "bz"])  # gauss, unnamed
    frame["F"] = PAPER_FIELD / 1e5  # a reference in the same unnamed unit
    frame.to_csv(tmp_path / "log.csv", index=False)
    memory = read_log(tmp_path / "log.csv", reference_column="F")
    with dask.config.set(scheduler="threads"):
        lazy = read_lazy_log(tmp_path / "log.csv", block_bytes=20_000, reference_column="F")
        np.testing.assert_array_equal(lazy.samples[::1], memory.samples)
        np.testing.assert_array_equal(lazy.reference[::1], memory.reference)
    for log in (memory, lazy):
        assert (log.unit, log.unit_source) == ("raw", "assumed") and "--unit G" in log.warnings[0]
    np.testing.assert_array_equal(memory.samples, frame[["bx", "by", "bz"]].to_numpy())


def test_rows_left_out_of_parquet_are_found_by_the_first_pass_as_in_memory(tmp_path):
    pytest.importorskip("pyarrow")
    from nlpcal.calibration import calibrate_log
    from nlpcal.io import read_log
    from nlpcal.io.lazy import read_lazy_log

    samples, _ = make_log(n=30_000, noise=1.0, seed=5)
    frame = pd.DataFrame(samples, columns=["bx", "by", "bz"])
    frame["proton_nT"] = PAPER_FIELD
    frame.loc[12_345, ["bx", "by", "bz"]] = 0.0  # a zero vector: always left out
    frame.loc[23_456, "by"] = np.nan  # dropped with drop_invalid
    frame.to_parquet(tmp_path / "log.parquet", index=False, row_group_size=10_000)
    options = {"drop_invalid": True, "reference_column": "proton_nT"}
    memory = read_log(tmp_path / "log.parquet", **options)
    expected = calibrate_log(memory, method="joint")
    with dask.config.set(scheduler="sync"):
        log = read_lazy_log(tmp_path / "log.parquet", keep=False, **options)
        assert log.dropped == 0 and log.samples.passes == 0  # the footers' rows, not read yet
        result = calibrate_log(log, method="joint")
    assert log.dropped == memory.dropped == 2 and result.n_samples == expected.n_samples
    assert set(memory.notes) <= set(log.notes)
    # the first pass found the blocks shorter than declared: it ran again on the rows counted
    names = [what for what, _ in log.samples.timings]
    assert names.count("MomentBlock + survey") == 2 and "survey" not in names
    assert_same_optimum(result.parameters, expected.parameters, expected.standard_errors)


@pytest.mark.parametrize("keep", [False, True])
def test_each_block_of_a_parquet_log_is_read_once_per_pass(tmp_path, monkeypatch, keep):
    pytest.importorskip("pyarrow")
    from nlpcal.calibration import calibrate_log
    from nlpcal.io import lazy as reader

    samples, _ = make_log(n=30_000, noise=1.0, seed=5)
    frame = pd.DataFrame(samples, columns=["bx", "by", "bz"])
    frame["proton_nT"] = PAPER_FIELD + np.sin(np.arange(len(frame)) / 300.0)
    frame.to_parquet(tmp_path / "log.parquet", index=False, row_group_size=5_000)
    reads = []
    original = reader._table_of
    monkeypatch.setattr(reader, "_table_of", lambda spec: reads.append(spec) or original(spec))
    with dask.config.set(scheduler="threads"):
        log = reader.read_lazy_log(
            tmp_path / "log.parquet", reference_column="proton_nT", keep=keep
        )
        calibrate_log(log, method="joint")
    # the samples, the reference column and the reader's checks of a pass share each read;
    # the first block is read apart for the frame of the first pass and the unit's check
    heads = sum(what == "head" for what, _ in log.samples.timings)
    if keep:  # read once, when opened: the passes and the first block read memory
        assert len(reads) == 6 and log.samples.passes == 2
    else:
        assert len(reads) == 6 * log.samples.passes + heads and heads <= 2


@pytest.mark.parametrize("kind", ["parquet", "csv"])
def test_a_log_that_fits_in_memory_is_read_once_for_every_pass(tmp_path, monkeypatch, kind):
    """Read when opened and kept in memory: its rows counted there (a zero vector and a row
    with a NaN left out, said in the same notes), the reweightings of a robust loss and the
    pass after the solve all read the blocks there, and the result is the one of the passes
    that read the files."""
    pytest.importorskip("pyarrow")
    from nlpcal import cluster
    from nlpcal.calibration import calibrate_log
    from nlpcal.io import lazy as reader

    samples, _ = make_log(n=30_000, noise=1.0, seed=5)
    frame = pd.DataFrame(samples, columns=["bx", "by", "bz"])
    frame["proton_nT"] = PAPER_FIELD
    frame.loc[12_345, ["bx", "by", "bz"]] = 0.0
    frame.loc[23_456, "by"] = np.nan
    path = tmp_path / f"log.{kind}"
    if kind == "parquet":
        frame.to_parquet(path, index=False, row_group_size=5_000)
    else:
        frame.to_csv(path, index=False)
    options = {"reference_column": "proton_nT", "drop_invalid": True, "block_bytes": 400_000}
    reads = []
    original = reader._table_of
    monkeypatch.setattr(reader, "_table_of", lambda spec: reads.append(spec) or original(spec))
    # room for it, whatever this machine has
    monkeypatch.setattr(cluster, "memory_to_keep", lambda: (1e10, "this machine"))
    results, logs = {}, {}
    with dask.config.set(scheduler="threads"):
        for keep in (False, True):
            reads.clear()
            logs[keep] = log = reader.read_lazy_log(path, keep=keep, **options)
            results[keep] = calibrate_log(log, method="joint", loss="huber")
            blocks = len({spec[1:3] if kind == "parquet" else spec[4] for spec in reads})
            notes = " ".join(log.notes)
            if keep:
                assert len(reads) == blocks and "read once and kept in memory" in notes
                assert log.samples.passes >= 3  # the moments, reweighted, after the solve
                assert [w for w, _ in log.samples.timings].count("MomentBlock + survey") == 1
            else:
                assert len(reads) > blocks * log.samples.passes
                assert "read in every pass" in notes
        # a log larger than the memory the scheduler may take stays in its files
        monkeypatch.setattr(cluster, "memory_to_keep", lambda: (1e5, "a small machine"))
        reads.clear()
        log = reader.read_lazy_log(path, **options)
        assert "read in every pass (its " in " ".join(log.notes)
        assert "exceed the 0.0954 MiB a small machine may take" in " ".join(log.notes)
        # the first block for the unit's check; a CSV log's rows counted
        assert len(reads) == 1 + (0 if kind == "parquet" else blocks)
    assert logs[True].dropped == logs[False].dropped == 2
    one_file = [SimpleNamespace(parquet=kind == "parquet")]
    what = "Parquet row group" if kind == "parquet" else "block"
    assert reader._where_note(None, "", 1, one_file).endswith(f": 1 {what} read in every pass")
    assert f"the log's 1 {what} is read once" in reader._where_note("1 MiB", "", 1, one_file)
    said = {
        keep: [n for n in log.notes if "every pass" not in n and "kept" not in n]
        for keep, log in logs.items()
    }
    assert sorted(said[True]) == sorted(said[False]) and any("(0, 0, 0)" in n for n in said[True])
    assert results[True].n_samples == results[False].n_samples == 30_000 - 2
    assert_same_calibration(results[False], results[True])


def test_blocks_are_kept_where_the_scheduler_has_room_for_them(monkeypatch, cluster):
    from nlpcal import chunks
    from nlpcal import cluster as where

    monkeypatch.setattr(chunks, "available_memory", lambda: 8e9)
    with dask.config.set(scheduler="threads"):
        assert where.memory_to_keep() == (where.KEEP_SHARE * 8e9, "this machine")
    with dask.config.set(scheduler="sync"):
        assert where.memory_to_keep() == (where.KEEP_SHARE * 8e9, "this machine")
    with dask.config.set(scheduler="processes"):  # each pass would send the blocks again
        assert where.memory_to_keep() is None
    monkeypatch.setattr(chunks, "available_memory", lambda: None)  # a machine that cannot tell
    with dask.config.set(scheduler="threads"):
        assert where.memory_to_keep() is None
    distributed = pytest.importorskip("distributed")
    with distributed.Client(cluster, set_as_default=False) as client, where.scheduler(client):
        room, on = where.memory_to_keep()  # the cluster's own workers
        limits = [w["memory_limit"] for w in where._workers(client)]
        assert 0 < room <= where.KEEP_SHARE * sum(limits) and "the workers of" in on
        # the worker with the least room decides, for every worker
        workers = [
            {"memory_limit": 1000, "metrics": {"memory": 100}},
            {"memory_limit": 1000, "metrics": {"memory": 300}},
        ]
        monkeypatch.setattr(where, "_workers", lambda _: workers)
        assert where.memory_to_keep()[0] == 2 * (500 - 300)
        workers[1] = {"memory_limit": 0}  # no limit: nothing is kept
        assert where.memory_to_keep() is None


def test_a_scheduler_that_answers_with_an_error_keeps_nothing():
    from nlpcal import cluster

    class Gone:
        def scheduler_info(self, **_):
            raise OSError("the scheduler is gone")

    assert cluster._workers(Gone()) == []


@pytest.mark.parametrize("zero_row", [None, 12_345])
def test_blocks_whose_rows_were_all_kept_are_screened_by_the_first_pass_only(
    tmp_path, monkeypatch, zero_row
):
    pytest.importorskip("pyarrow")
    from nlpcal.calibration import calibrate_log
    from nlpcal.io import lazy as reader
    from nlpcal.io import read_log
    from nlpcal.io.rows import RowScreen

    samples, _ = make_log(n=30_000, noise=1.0, seed=5)
    frame = pd.DataFrame(samples, columns=["bx", "by", "bz"])
    frame.loc[7_001:7_020, ["bx", "by", "bz"]] = frame.loc[7_000, ["bx", "by", "bz"]].to_numpy()
    if zero_row is not None:  # a zero vector, left out: its block is screened in every pass
        frame.loc[zero_row, ["bx", "by", "bz"]] = 0.0
    frame.to_parquet(tmp_path / "log.parquet", index=False, row_group_size=5_000)
    memory = read_log(tmp_path / "log.parquet", reference_field=PAPER_FIELD)
    expected = calibrate_log(memory, method="staged")
    screened = []
    original = RowScreen.keep
    monkeypatch.setattr(
        RowScreen, "keep", lambda self, *args: screened.append(1) or original(self, *args)
    )
    with dask.config.set(scheduler="sync"):
        log = reader.read_lazy_log(
            tmp_path / "log.parquet", reference_field=PAPER_FIELD, keep=False
        )
        result = calibrate_log(log, method="staged")
    heads = sum(what == "head" for what, _ in log.samples.timings)
    if zero_row is None:  # six blocks screened by the first pass, none after
        assert log.samples.passes == 2 and len(screened) == 6 + heads
    else:  # the first pass again on the rows counted, then the pass after the solve: 1 each
        assert log.samples.passes == 3 and len(screened) == 6 + 1 + 1 + heads
        assert log.dropped == memory.dropped == 1
    # the 20 repeats (kept: no drop_invalid) are counted once, as in memory
    assert [n for n in log.notes if "repeat" in n] == [n for n in memory.notes if "repeat" in n]
    assert "repeat the field vector" in " ".join(log.notes)
    assert_same_optimum(result.parameters, expected.parameters, expected.standard_errors)


@pytest.fixture(scope="module")
def long_log(tmp_path_factory):
    """A Parquet log whose robust calibration on two workers takes seconds: long enough to be
    interrupted in its passes."""
    pytest.importorskip("pyarrow")
    samples, _ = make_log(n=1_000_000, noise=1.0, seed=37)
    path = tmp_path_factory.mktemp("long") / "log.parquet"
    frame = pd.DataFrame(samples, columns=["bx", "by", "bz"])
    frame.to_parquet(path, index=False, row_group_size=100_000)
    return path


def session_processes(session: int) -> list:
    """The processes of a session that still run (zombies are gone but for their parent)."""
    psutil = pytest.importorskip("psutil")
    alive = []
    for process in psutil.process_iter(["status"]):
        with contextlib.suppress(psutil.Error, OSError):
            if os.getsid(process.pid) == session and process.info["status"] != "zombie":
                alive.append(process)
    return alive


@pytest.mark.slow  # end to end, seconds
@pytest.mark.parametrize("scheduler", ["local", "processes"])
@pytest.mark.parametrize(
    ("number", "said", "status"),
    [(signal.SIGINT, "interrupted", 130), (signal.SIGTERM, "terminated", 143)],
    ids=["ctrl-c", "sigterm"],
)
def test_a_signal_to_the_group_on_a_scheduler_is_one_line_and_ends_every_worker(
    long_log, tmp_path, scheduler, number, said, status
):
    """A terminal's Ctrl-C, or a `kill` of the process group, reaches every process of the
    group: the workers leave it to nlpcal, which closes them and says so once; no traceback, no
    hang (a processes worker ended as it wrote a result left the pool waiting), no process
    left, -o as it was."""
    if scheduler == "local":
        pytest.importorskip("distributed")
    pytest.importorskip("psutil")
    output = tmp_path / "params.json"
    output.write_text('{"kept": true}\n')
    argv = ["calibrate", long_log, "--scheduler", scheduler, "--workers", "2", "--loss", "huber"]
    # Python's handler of SIGINT set first: a shell without job control (CI's) starts its
    # background commands with SIGINT ignored, which they and theirs inherit
    start = (
        "import runpy, signal; signal.signal(signal.SIGINT, signal.default_int_handler); "
        "runpy.run_module('nlpcal', run_name='__main__', alter_sys=True)"
    )
    run = subprocess.Popen(
        [sys.executable, "-c", start, *map(str, argv), "-o", str(output)],
        cwd=tmp_path,
        env={**os.environ, "PYTHONPATH": str(Path(nlpcal.__file__).parents[1])},
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,
    )
    lines = []
    try:
        for line in run.stderr:  # its passes start after this line
            lines.append(line)
            if line.startswith("nlpcal: running on"):
                break
        time.sleep(0.3)
        os.killpg(run.pid, number)
        # read on the side: a run that hangs keeps its stderr open
        reader = threading.Thread(target=lambda: lines.extend(run.stderr), daemon=True)
        reader.start()
        try:
            code = run.wait(timeout=60)
        except subprocess.TimeoutExpired:
            code = "hung"
            os.killpg(run.pid, signal.SIGKILL)
        reader.join(timeout=10)
    finally:
        if run.poll() is None:
            os.killpg(run.pid, signal.SIGKILL)
    stderr = "".join(lines)
    deadline = time.monotonic() + 10
    while session_processes(run.pid) and time.monotonic() < deadline:
        time.sleep(0.1)
    assert code in (status, -number), stderr  # or ended by the signal: $? = 128 + number
    assert "Traceback" not in stderr, stderr
    # nlpcal's notes aside, and CasADi's own warning when the Ctrl-C lands inside an IPOPT
    # solve of this process (printed by its C++ interface, which nlpcal does not control)
    told = [
        line
        for line in lines
        if not line.startswith("nlpcal: ") and "KeyboardInterruptException" not in line
    ]
    assert told == [f"nlpcal calibrate: {said}\n"], stderr
    assert output.read_text() == '{"kept": true}\n'
    assert sorted(p.name for p in tmp_path.iterdir()) == ["params.json"]
    assert session_processes(run.pid) == []
