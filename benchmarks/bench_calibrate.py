"""Calibration cost against the number of samples, as ratios to one Gram pass over the same data.

For N = 1e3, 1e4, 1e5, 1e6 (uniform attitudes, 1 nT noise, reference field given) it measures,
in one process and on the same array:

- gram: one numpy pass that builds the 10 x 10 Gram matrix of the quadratic monomials
  (x^2, y^2, z^2, xy, xz, yz, x, y, z, 1): no full fit can read the data faster;
- joint: nlpcal.calibrate(method="joint"), cold: the problem caches are cleared before every
  repeat, so problem construction is included, as a first call pays it;
- staged: nlpcal.calibrate(method="staged"), 7 cycles with their Table 1 rows, cold as well;
- joint warm, staged warm: the calls a process calibrating one log after another makes, the
  problems built by an untimed call first: the joint solve as above, and the staged cycle with
  its default stop rules (the cycles its rtol rule takes), `--warm-repeats` times;
- scipy: scipy.optimize.least_squares on the geometric residual |B1_i| - F, from the same start;

and prints medians over the repeats (the warm ones with their spread, min-max), their ratios to
the Gram pass, IPOPT iterations and the peak memory that tracemalloc sees during one more
(untimed) call. Each size runs with each kernel of the data pass (`nlpcal.compiled`): numpy,
and the compiled one where numba is installed (loaded before the timed calls: the load, in a
new process, is printed on its own).

    python benchmarks/bench_calibrate.py [--sizes 1e3 2e3 1e4 1e5 1e6] [--repeats 5]
        [--warm-repeats 21] [--kernels numpy numba]

With --pass-costs it prints instead the data pass's cost per sample for each feature set
(`pass_costs`): the distinct moments gathered now, with each kernel, beside the Gram matrix of
features gathered before (tests/gram_reference.py), in the same run.

    python benchmarks/bench_calibrate.py --pass-costs [--sizes 1e6] [--repeats 7]
"""

from __future__ import annotations

import argparse
import contextlib
import os
import platform
import statistics
import subprocess
import sys
import time
import tracemalloc

import casadi
import numpy as np

import nlpcal
from nlpcal import compiled
from nlpcal.calibration.joint import joint_start
from nlpcal.models.zhou2010 import correction_matrix_entries
from nlpcal.moments import accumulate
from nlpcal.nlp import blocks as problems
from nlpcal.nlp.solver import PROBLEMS
from nlpcal.simulation import ZHOU2010_FIELD_NT, simulate

FIELD = ZHOU2010_FIELD_NT


def gram_pass(samples):
    x, y, z = samples.T
    features = np.column_stack([x * x, y * y, z * z, x * y, x * z, y * z, x, y, z, np.ones_like(x)])
    return features.T @ features


@contextlib.contextmanager
def kernel(name: str):
    """The data pass runs the kernel `name` ("numpy" or "numba") inside the block."""
    before = os.environ.get(compiled.KERNEL_VARIABLE)
    os.environ[compiled.KERNEL_VARIABLE] = name
    try:
        yield
    finally:
        if before is None:
            del os.environ[compiled.KERNEL_VARIABLE]
        else:
            os.environ[compiled.KERNEL_VARIABLE] = before


def kernels_available() -> list:
    return ["numpy", "numba"] if compiled.available() else ["numpy"]


def kernel_load_s(repeats: int) -> str:
    """Median (min-max) of the compiled kernel's load in a new process (`compiled.load`):
    numba's import and the kernel read from numba's cache (compiled there by an untimed first
    process). [s]"""
    code = (
        "import time\n"
        "started = time.perf_counter()\n"
        "from nlpcal import compiled\n"
        "compiled.load()\n"
        "print(time.perf_counter() - started)\n"
    )
    run = [sys.executable, "-c", code]
    subprocess.run(run, check=True, capture_output=True)
    times = [
        float(subprocess.run(run, check=True, capture_output=True, text=True).stdout)
        for _ in range(repeats)
    ]
    return f"{statistics.median(times):.3f} ({min(times):.3f}-{max(times):.3f})"


def cold(function):
    """Run `function` with every cached CasADi problem, and the evaluations built on them,
    dropped first."""
    for builder, _ in PROBLEMS.values():
        builder.cache_clear()
    problems._evaluation.cache_clear()
    return function()


def joint(samples):
    return nlpcal.calibrate(samples, method="joint", reference_field=FIELD)


def staged(samples):
    return nlpcal.calibrate(samples, method="staged", reference_field=FIELD, cycles=7, rtol=0.0)


def staged_default(samples):
    return nlpcal.calibrate(samples, method="staged", reference_field=FIELD)


def scipy_least_squares(samples):
    from scipy.optimize import least_squares

    start = joint_start(accumulate(samples[:20000], FIELD))

    def residual(theta):
        M = np.array(
            correction_matrix_entries(theta[6], theta[7], theta[8], theta[3], theta[4], theta[5])
        )
        return np.linalg.norm((samples - theta[:3]) @ M.T, axis=1) - FIELD

    return least_squares(residual, start, x_scale=problems.variable_scale(FIELD))


def timed(function, samples, repeats):
    times, result = timings(function, samples, repeats)
    return statistics.median(times), result


def timings(function, samples, repeats):
    """(the wall time of each of `repeats` calls [s], the last result)."""
    times, result = [], None
    for _ in range(repeats):
        started = time.perf_counter()
        result = function(samples)
        times.append(time.perf_counter() - started)
    return times, result


def warm(function, samples, repeats, gram_s) -> tuple:
    """Table cells of a warm call (the problems built by one untimed call first): the median
    with its spread (min-max) [s], and the median's ratio to the Gram pass."""
    function(samples)
    times, _ = timings(function, samples, repeats)
    median = statistics.median(times)
    return (
        f"{median:.5f} ({min(times):.5f}-{max(times):.5f})",
        f"{median / gram_s:.1f}",
    )


def peak_mib(function, samples) -> float:
    tracemalloc.start()
    function(samples)
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    return peak / 2**20


def machine() -> str:
    return (
        f"{platform.processor() or platform.machine()}, {os.cpu_count()} cores, "
        f"Python {platform.python_version()}, numpy {np.__version__}, "
        f"casadi {casadi.__version__}, nlpcal {nlpcal.__version__}"
    )


def pass_costs(n: int, repeats: int) -> None:
    """The data pass's cost per sample [ns] for each feature set, beside the number of distinct
    moments it needs: the moment passes (`nlpcal.moments.MomentBlock`, the lag's `LagBlock`,
    the channels' `ChannelGram`) and the Gram matrix of the features as gathered before
    (`FeatureGram` of tests/gram_reference.py: its figure leaves out the Table 1 sums the
    moment pass also gathers). Each repeat times every pass once, in turn, through
    `nlpcal.passes.reduce` (the pass's threads); medians with their spread (min-max)."""
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
    from gram_reference import FeatureGram

    from nlpcal import lag
    from nlpcal.auxiliary import moments as aux
    from nlpcal.moments import CHUNK_ROWS, MomentBlock, gram_moments, layout, sphere_frame
    from nlpcal.passes import reduce

    samples = simulate(n, noise=1.0, seed=1).to_numpy()
    rng = np.random.default_rng(2)
    series = FIELD * (1.0 + 1e-3 * np.sin(np.linspace(0.0, 60.0, n)))
    times = np.arange(n) * 0.1
    channels = np.column_stack([rng.uniform(0.0, 40.0, n), rng.normal(3.0, 1.0, n)])
    frame = sphere_frame(samples)
    centre = frame.centre
    moments = accumulate(samples, series, frame=frame)
    length = moments.length
    cframe = aux.channel_frame(channels)
    scaled = (channels - cframe.centre) / cframe.scale
    store = lag.Series(series, times)

    def new_moments(reference, is_series):
        block = MomentBlock(
            centre, FIELD if not is_series else length, is_series, FIELD, fast=compiled.use(n)
        )
        return reduce(samples, reference, block, lambda a, b: a, CHUNK_ROWS)

    def old_gram(reference, is_series):
        block = FeatureGram(centre, FIELD if not is_series else length, is_series)
        return reduce(samples, reference, block, np.add, CHUNK_ROWS)

    def new_lag():
        return lag.lag_moments(samples, series, times, moments, noise=0.0)

    def old_lag():
        block = FeatureGram(centre, length, True)

        def work(rows, ref, start):
            R, D, _, _ = store.columns(start, len(rows))
            return block(rows, R, derivative=D)

        return reduce(samples, series, work, np.add, CHUNK_ROWS, indexed=True)

    def new_channels():
        block = aux.ChannelGram(centre, FIELD, cframe, False, fast=compiled.use(n))
        return reduce(samples, channels, block, np.add, CHUNK_ROWS)

    def old_channels():
        block = FeatureGram(centre, FIELD, False, channels=2)
        return reduce(
            samples, scaled, lambda rows, extra: block(rows, None, extra=extra), np.add, CHUNK_ROWS
        )

    lag_set = lag.lag_moment_set(layout(True))[0]
    channel_set = aux.channel_moments(False, 2)[0]
    constant, varying = gram_moments(False), gram_moments(True)
    sets = {  # name: (distinct moments, features, new passes, old passes)
        "constant reference": (
            constant.size,
            46,
            [lambda: new_moments(FIELD, False)],
            [lambda: old_gram(FIELD, False)],
        ),
        "reference series": (
            varying.size,
            58,
            [lambda: new_moments(series, True)],
            [lambda: old_gram(series, True)],
        ),
        "series + derivative": (
            varying.size + lag_set.size,
            58,
            [lambda: new_moments(series, True), new_lag],
            [lambda: old_gram(series, True), old_lag],
        ),
        "constant + 2 channels": (
            constant.size + channel_set.size,
            46 + 148,
            [lambda: new_moments(FIELD, False), new_channels],
            [lambda: old_gram(FIELD, False), old_channels],
        ),
    }
    kernels = kernels_available()
    calls = {("gram10", "numpy"): [lambda: gram_pass(samples)]}
    for name, (_, _, new, old) in sets.items():
        calls[name + " old", "numpy"] = old
        for kind in kernels:
            calls[name + " new", kind] = new
    times_ns: dict = {key: [] for key in calls}
    for (_, kind), passes in calls.items():  # warm: plans, caches and the kernel loaded
        with kernel(kind):
            for call in passes:
                call()
    for _ in range(repeats):
        for key, passes in calls.items():
            with kernel(key[1]):
                started = time.perf_counter()
                for call in passes:
                    call()
                times_ns[key].append((time.perf_counter() - started) / n * 1e9)

    def cell(values):
        return f"{statistics.median(values):.1f} ({min(values):.1f}-{max(values):.1f})"

    print(f"# machine: {machine()}")
    print(f"# N = {n:.0e}, {repeats} repeats: medians (min-max) [ns per sample]")
    print(f"# one numpy 10-feature Gram pass (gram_pass): {cell(times_ns['gram10', 'numpy'])}")
    header = ["feature set", "distinct moments", "features (Gram)", "old Gram ns/sample"]
    for kind in kernels:
        header += [f"moments {kind} ns/sample", f"{kind}/Gram", f"{kind}/gram10"]
    print(" | ".join(header))
    gram10 = statistics.median(times_ns["gram10", "numpy"])
    for name, (distinct, features, _, _) in sets.items():
        old = times_ns[name + " old", "numpy"]
        row = [name, str(distinct), str(features), cell(old)]
        for kind in kernels:
            new = times_ns[name + " new", kind]
            row += [
                cell(new),
                f"{statistics.median(new) / statistics.median(old):.2f}",
                f"{statistics.median(new) / gram10:.2f}",
            ]
        print(" | ".join(row), flush=True)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=float, nargs="+", default=[1e3, 2e3, 1e4, 1e5, 1e6])
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--warm-repeats", type=int, default=21, help="repeats of a warm call")
    parser.add_argument("--no-scipy", action="store_true", help="skip the scipy baseline")
    parser.add_argument("--pass-costs", action="store_true", help="the pass per feature set")
    parser.add_argument(
        "--kernels", nargs="+", choices=["numpy", "numba"], help="default: both where numba is"
    )
    args = parser.parse_args(argv)
    if args.pass_costs:
        return pass_costs(int(max(args.sizes)), args.repeats)
    kernels = args.kernels or kernels_available()
    print(f"# machine: {machine()}")
    print(
        f"# medians over {args.repeats} repeats ({args.warm_repeats} warm, with their min-max); "
        f"ratios to the Gram pass on the same array"
    )
    if "numba" in kernels:
        print(f"# compiled kernel's load in a new process [s]: {kernel_load_s(args.repeats)}")
    header = (
        "N",
        "kernel",
        "gram_s",
        "joint_s",
        "joint/gram",
        "staged_s",
        "staged/gram",
        "joint_warm_s",
        "joint_warm/gram",
        "staged_warm_s",
        "staged_warm/gram",
        "scipy_s",
        "scipy/gram",
        "joint_it",
        "staged_it",
        "peak_joint_MiB",
        "peak_staged_MiB",
        "data_MiB",
    )
    print(" | ".join(header))
    for size in args.sizes:
        n = int(size)
        samples = simulate(n, noise=1.0, seed=1).to_numpy()
        gram_s, _ = timed(gram_pass, samples, args.repeats)
        for kind in kernels:
            with kernel(kind):
                if kind == "numba":
                    compiled.load()  # before the timed calls
                measure(samples, n, kind, gram_s, args)


def measure(samples, n: int, kind: str, gram_s: float, args) -> None:
    """One row of the table: N samples with the kernel `kind`."""
    joint_s, joint_result = timed(lambda x: cold(lambda: joint(x)), samples, args.repeats)
    staged_s, staged_result = timed(lambda x: cold(lambda: staged(x)), samples, args.repeats)
    joint_warm = warm(joint, samples, args.warm_repeats, gram_s)
    staged_warm = warm(staged_default, samples, args.warm_repeats, gram_s)
    if args.no_scipy:
        scipy_s = float("nan")
    else:
        scipy_s, _ = timed(scipy_least_squares, samples, max(1, min(args.repeats, 3)))
    row = (
        f"{n:.0e}",
        kind,
        f"{gram_s:.6f}",
        f"{joint_s:.4f}",
        f"{joint_s / gram_s:.1f}",
        f"{staged_s:.4f}",
        f"{staged_s / gram_s:.1f}",
        *joint_warm,
        *staged_warm,
        f"{scipy_s:.3f}",
        f"{scipy_s / gram_s:.1f}",
        str(joint_result.solver.iterations),
        str(staged_result.solver.iterations),
        f"{peak_mib(joint, samples):.1f}",
        f"{peak_mib(staged, samples):.1f}",
        f"{samples.nbytes / 2**20:.1f}",
    )
    print(" | ".join(row), flush=True)


if __name__ == "__main__":
    main()
