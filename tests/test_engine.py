"""The shape of the package: one build-once idiom, arrows that run one way, units in the library,
and every feature's verbs importable from `nlpcal`."""

from __future__ import annotations

import ast
import signal
from pathlib import Path

import numpy as np
import pytest

import nlpcal
from nlpcal import interruptions
from nlpcal.nlp.solver import PROBLEMS, builds
from resolution import assert_same_optimum
from synthetic import PAPER_FIELD, PAPER_TRUTH, make_log

PACKAGE = Path(nlpcal.__file__).resolve().parent

#: Layers from the bottom up; a module may import its own layer and the ones below.
LAYERS = {
    "models": 0,
    "defaults": 0,
    "errors": 1,
    "interruptions": 1,
    "version": 1,
    "units": 1,
    "validation": 1,
    "inference": 1,
    "results": 1,
    "schemas": 1,
    "verdict": 1,
    "robust": 1,
    "io": 1,
    "live": 2,
    "statistics": 1,
    "chunks": 1,
    "passes": 1,
    "cluster": 1,
    "moments": 1,
    "monomials": 1,
    "compiled": 1,
    "_moment_kernel": 1,
    "_score_kernel": 1,
    "plots": 1,
    "geomagnetic": 1,
    "timing": 1,
    "nlp": 1,
    "auxiliary": 1,
    "lag": 1,
    "delta_f": 1,
    "calibration": 2,
    "comparison": 2,
    "compass": 2,
    "drift": 2,
    "orthogonality": 2,
    "simulation": 2,
    "correction": 2,
    "formats": 2,
    "report": 2,
    "batch": 2,
    "reproduce": 2,
    "platform": 2,
    "cli": 3,
    "__main__": 3,
    "__init__": 3,
}


def _modules():
    for path in sorted(PACKAGE.rglob("*.py")):
        parts = path.relative_to(PACKAGE).with_suffix("").parts
        yield path, parts


def _imports(path, parts):
    """(imported nlpcal top-level name, inside a function?) for every import of a module."""
    tree = ast.parse(path.read_text())
    package = parts[:-1]  # the folder of the module (of its __init__ too)
    inside = set()
    for node in ast.walk(tree):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            inside.update(id(n) for n in ast.walk(node) if n is not node)
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom):
            if node.level:
                base = list(package[: len(package) - (node.level - 1)])
                target = base + (node.module.split(".") if node.module else [])
                names = [target + [alias.name] for alias in node.names] if not target else [target]
            elif node.module and node.module.startswith("nlpcal"):
                names = [node.module.split(".")[1:] or ["__init__"]]
            else:
                continue
            for name in names:
                yield (name[0] if name else "__init__"), id(node) in inside
        elif isinstance(node, ast.Import):
            for alias in node.names:
                if alias.name.startswith("nlpcal."):
                    yield alias.name.split(".")[1], id(node) in inside


#: Modules imported inside a function, where they are needed, and why.
LAZY = {
    "_moment_kernel": "it imports numba, an optional extra that takes 0.15-0.3 s to import",
    "_score_kernel": "it imports numba, as _moment_kernel does",
}


def test_imports_run_one_way_cli_features_shared_models():
    problems = []
    for path, parts in _modules():
        layer = LAYERS[parts[0]]
        for target, in_function in _imports(path, parts):
            if LAYERS.get(target, 3) > layer:
                problems.append(f"{'/'.join(parts)} imports {target} (a higher layer)")
            if in_function and parts[0] != "cli" and target not in LAZY:
                problems.append(f"{'/'.join(parts)} imports {target} inside a function")
    assert not problems, "\n".join(problems)


def test_every_problem_is_built_once_and_does_not_grow_with_the_log():
    # Every registered builder gives the same object for the same arguments.
    for name, (builder, examples) in PROBLEMS.items():
        for args in examples:
            assert builder(*args) is builder(*args), name
    assert {name.split(".")[0] for name in PROBLEMS} == {
        "zhou2010",
        "wang2015",
        "liu2022",
        "qiu2017",
    }

    def run_every_feature(n, seed):
        samples, _ = make_log(n=n, noise=1.0, seed=seed)
        for method in ("staged", "joint"):
            for model in ("full", "diagonal", "offset"):
                nlpcal.calibrate(samples, method=method, cycles=5, model=model)
                nlpcal.calibrate(
                    samples, method=method, cycles=5, model=model, reference_field=PAPER_FIELD
                )
        current = np.random.default_rng(seed).uniform(0.0, 40.0, n)  # aux channels too
        for reference in (None, PAPER_FIELD):
            nlpcal.calibrate(
                samples + np.outer(current, (120.0, -80.0, 300.0)),
                method="joint",
                reference_field=reference,
                aux_columns={"current": current},
            )
        probe = nlpcal.orthogonality.synthetic_rotation((0.07, 0.04, 0.1), n=n, seed=seed)
        nlpcal.invert(probe)
        nlpcal.invert(probe, field_nT=55_000.0)
        temperature = np.linspace(0.0, 10.0, n)
        nlpcal.calibrate_temperature(
            samples * (1 + 1e-4 * temperature[:, None]), temperature, np.full(n, PAPER_FIELD)
        )

    run_every_feature(300, 1)
    built = builds()
    run_every_feature(1700, 2)  # other lengths, other data: nothing is built again
    assert builds() == built


@pytest.mark.parametrize("number", interruptions.SIGNALS, ids=lambda n: signal.Signals(n).name)
def test_a_signal_while_a_problem_is_built_reaches_the_caller(monkeypatch, number):
    """CasADi converts the arguments of a symbolic operation with the C API's hasattr, which runs
    the Python `shape` of an SX or MX and drops what it raises. A Ctrl-C (or the command line's
    SIGTERM) landing there was lost and the run went on; a build now acts on it as it ends."""
    import casadi as ca

    from nlpcal.nlp.blocks import objective_function

    landed = []

    def shape_as_the_signal_lands(shape):
        def read(self):
            if not landed:  # once: the handler runs here, inside CasADi's conversion
                landed.append(True)
                signal.raise_signal(number)
            return shape.fget(self)

        return property(read)

    for symbol in (ca.SX, ca.MX):
        monkeypatch.setattr(symbol, "shape", shape_as_the_signal_lands(symbol.shape))
    # Python's handler, as a terminal's Python has it (CI's shell starts legs with SIGINT ignored)
    previous = signal.signal(number, signal.default_int_handler)
    try:
        with pytest.raises(KeyboardInterrupt):
            objective_function.__wrapped__("none")  # a build, not the cached problem
    finally:
        signal.signal(number, previous)
    assert landed


def test_a_held_signal_acts_as_its_block_ends_and_a_second_at_once_where_the_block_says():
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    reached = []
    try:
        with pytest.raises(KeyboardInterrupt), interruptions.deferred():
            signal.raise_signal(signal.SIGINT)
            signal.raise_signal(signal.SIGINT)
            reached.append("the end of the block")
        with pytest.raises(KeyboardInterrupt), interruptions.deferred(second_acts=True):
            signal.raise_signal(signal.SIGINT)
            reached.append("past the first")
            signal.raise_signal(signal.SIGINT)
            reached.append("past the second")
        assert reached == ["the end of the block", "past the first"]
        assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
    finally:
        signal.signal(signal.SIGINT, previous)


def test_the_library_takes_units():
    samples, _ = make_log(n=1500, noise=1.0, seed=5)
    in_nT = nlpcal.calibrate(samples, method="joint", reference_field=PAPER_FIELD)
    in_uT = nlpcal.calibrate(
        samples / 1000.0, unit="uT", reference_field=PAPER_FIELD / 1000.0, method="joint"
    )
    mixed = nlpcal.calibrate(
        samples / 1000.0,
        unit="uT",
        reference_field=PAPER_FIELD,
        reference_unit="nT",
        method="joint",
    )
    for result in (in_uT, mixed):
        assert result.unit == "nT"
        assert_same_optimum(result.parameters, in_nT.parameters, in_nT.standard_errors)
        for name, se in in_nT.standard_errors.items():  # in nT too; they move with the point
            assert result.standard_errors[name] == pytest.approx(se, rel=1e-3), name  # by 1e-9
    assert in_uT.parameters["z_x"] == pytest.approx(PAPER_TRUTH["z_x"], abs=0.5)
    corrected = in_uT.apply(samples / 1000.0, unit="uT")
    # the same parameters applied to the same samples in another unit: rounding only
    np.testing.assert_allclose(
        corrected * 1000.0, in_uT.apply(samples), rtol=1e-12, atol=1e-9
    )  # nT
    with pytest.raises(nlpcal.InputError, match="raw"):
        nlpcal.calibrate(samples, unit="raw", reference_field=PAPER_FIELD, reference_unit="nT")


def test_every_verb_and_result_type_is_importable_from_nlpcal():
    for name in nlpcal.__all__:
        assert getattr(nlpcal, name) is not None, name
    for verb in (
        "calibrate",
        "compare",
        "worst_case",
        "invert",
        "repeatability",
        "fit_drift",
        "calibrate_temperature",
        "calibrate_turns",
        "calibrate_free",
        "attitude",
        "evaluate",
        "simulate",
        "read_log",
    ):
        assert callable(getattr(nlpcal, verb)), verb
    with pytest.raises(AttributeError):
        nlpcal.not_a_verb  # noqa: B018


def test_every_result_type_shares_the_document_base():
    from nlpcal.results import Document

    kinds = [
        nlpcal.CalibrationResult,
        nlpcal.TemperatureCalibrationResult,
        nlpcal.DriftFit,
        nlpcal.CompassCalibration,
        nlpcal.Comparison,
        nlpcal.WorstCase,
        nlpcal.Inversion,
        nlpcal.Repeatability,
    ]
    formats = set()
    for kind in kinds:
        assert issubclass(kind, Document)
        assert kind.FORMAT.startswith("nlpcal-") and kind.FORMAT not in formats
        formats.add(kind.FORMAT)
    result = nlpcal.worst_case((0.1, 0.1, 0.1), 55_000.0)
    again = nlpcal.WorstCase.from_json(result.to_json())
    assert again.max_abs_error_nT == pytest.approx(result.max_abs_error_nT, rel=1e-15)
    assert again.to_dict() == result.to_dict()
