"""Type checkers see the public API: `py.typed` ships, every name of `nlpcal.__all__` has a type
(not `Any`: the lazy `__getattr__` would give Any without the TYPE_CHECKING imports), and a user
script that calls it checks clean. mypy runs on the package as installed: in CI's lint leg, the
wheel. Marked slow (mypy takes tens of seconds): the suites under other kernels leave it out."""

from __future__ import annotations

import ast
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

import nlpcal

pytestmark = pytest.mark.slow

HERE = Path(__file__).resolve().parent
PACKAGE = Path(nlpcal.__file__).resolve().parent
ROOT = HERE.parent


def run_mypy(script: str, folder: Path, package_root: Path | None = None) -> str:
    """mypy's report on a script (its lines about the script only: a package found as source,
    not installed, has its own lines about its dependencies' stubs), finding packages as the
    user's interpreter does, or under `package_root`, for a package that is not installed."""
    pytest.importorskip("mypy")
    path = folder / "script.py"
    path.write_text(script)
    env = dict(os.environ)
    env.pop("MYPYPATH", None)
    if package_root is not None:
        env["MYPYPATH"] = str(package_root)
    elif (PACKAGE.parent / "pyproject.toml").exists():  # the source tree (an editable install)
        env["MYPYPATH"] = str(PACKAGE.parent)
    done = subprocess.run(
        [
            sys.executable,
            "-m",
            "mypy",
            "--python-executable",
            sys.executable,
            "--no-incremental",
            "--cache-dir",
            os.devnull,
            "--config-file",
            os.devnull,
            "--python-version",
            "3.11",  # as the package's own mypy configuration
            path.name,
        ],
        capture_output=True,
        text=True,
        cwd=folder,
        env=env,
        check=False,
    )
    lines = (done.stdout + done.stderr).splitlines()
    return "\n".join(line for line in lines if line.startswith("script.py:") or ": " not in line)


def revealed(report: str) -> dict:
    """name -> the type mypy revealed for it, from lines `script.py:N: note: Revealed type is`."""
    found = {}
    for line in report.splitlines():
        if "Revealed type is" in line:
            number = int(line.split(":")[1])
            found[number] = line.split("Revealed type is ", 1)[1].strip().strip('"')
    return found


def untyped_names(
    package: str, names: list, folder: Path, package_root=None, script: str = ""
) -> dict:
    """The names of `package` whose type mypy reveals as Any, with mypy's errors if any, on a
    script (one mypy run for both: each takes tens of seconds) followed by a reveal_type line
    per name."""
    lines = script.splitlines() + [f"import {package}"]
    first = len(lines) + 1
    lines += [f"reveal_type({package}.{name})" for name in names]
    report = run_mypy("\n".join(lines) + "\n", folder, package_root)
    types = revealed(report)
    missing = [name for i, name in enumerate(names, start=first) if types.get(i, "Any") == "Any"]
    errors = [line for line in report.splitlines() if ": error:" in line]
    return {"Any": missing, "errors": errors}


def test_py_typed_ships_with_the_package():
    assert (PACKAGE / "py.typed").is_file()
    config = (ROOT / "pyproject.toml").read_text()
    assert 'nlpcal = ["py.typed"' in config  # the schemas ship beside it


def test_the_type_checking_imports_are_the_lazy_exports():
    tree = ast.parse((PACKAGE / "__init__.py").read_text())
    typed = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.If) and ast.unparse(node.test) == "TYPE_CHECKING":
            for child in ast.walk(node):
                if isinstance(child, ast.ImportFrom):
                    typed.update(alias.asname or alias.name for alias in child.names)
    assert typed == set(nlpcal._EXPORTS)
    assert set(nlpcal.__all__) == {"__version__", *nlpcal._EXPORTS}


USER_SCRIPT = (HERE / "typing" / "user_script.py").read_text()


def test_a_user_script_checks_clean_and_no_public_name_is_any(tmp_path):
    found = untyped_names("nlpcal", list(nlpcal.__all__), tmp_path, script=USER_SCRIPT)
    assert found == {"Any": [], "errors": []}


def test_the_check_finds_an_untyped_lazy_export(tmp_path):
    # a package like nlpcal, with py.typed, whose second lazy export has no TYPE_CHECKING import
    package = tmp_path / "root" / "lazypkg"
    package.mkdir(parents=True)
    (package / "py.typed").write_text("")
    core = "def typed(x: int) -> int:\n    return x\n\n\nuntyped = typed\n"
    (package / "core.py").write_text(core)
    (package / "__init__.py").write_text(
        textwrap.dedent(
            """\
            from __future__ import annotations
            import importlib
            from typing import TYPE_CHECKING

            if TYPE_CHECKING:
                from .core import typed

            __all__ = ["typed", "untyped"]


            def __getattr__(name: str):
                return getattr(importlib.import_module(".core", __name__), name)
            """
        )
    )
    (tmp_path / "work").mkdir()
    found = untyped_names("lazypkg", ["typed", "untyped"], tmp_path / "work", tmp_path / "root")
    assert found["Any"] == ["untyped"]


def test_the_checker_sees_the_signatures(tmp_path):
    # a keyword calibrate does not take is caught
    wrong = USER_SCRIPT.replace("cycles=20", "cycle=20")
    assert wrong != USER_SCRIPT
    report = run_mypy(wrong, tmp_path)
    assert 'Unexpected keyword argument "cycle" for "calibrate"' in report, report


def test_the_user_script_runs():
    sys.path.insert(0, str(HERE / "typing"))
    try:
        import user_script
    finally:
        sys.path.remove(str(HERE / "typing"))
    parameters, corrected = user_script.calibrate_example()
    assert set(parameters) >= {"z_x", "s_x", "alpha_deg"}
    assert corrected.shape == (600, 3)
    # three angles of e = 0.1 deg: to first order dB = (B / 2) u^T G u, G's eigenvalues (e, e, -2e)
    # [rad], so the largest positive error is B e / 2 (Wang et al. 2015) [nT]
    e = np.radians(0.1)
    assert user_script.worst_case_example() == pytest.approx(55_000 * e / 2, rel=0.01)


RESULT_FIELDS = {
    "result.parameters": "dict[str, float]",
    "result.standard_errors": "dict[str, float] | None",
    "result.statistics[-1]": "nlpcal.results.TableRow",
    "result.statistics[-1].std": "float | None",
    "result.identifiability": "nlpcal.calibration.result.Identifiability",
    "result.identifiability.not_identifiable": "list[str] | None",
    "result.input": "nlpcal.results.Provenance",
    "result.warnings": "list[str]",
}


def test_a_results_records_have_real_types(tmp_path):
    # the typed records of a result (a Table 1 row, identifiability, provenance) are seen as
    # such, and a misspelt field of a row is an error, not a KeyError at run time
    lines = ["import nlpcal", "result = nlpcal.calibrate([[1.0, 2.0, 3.0]])"]
    first = len(lines) + 1
    lines += [f"reveal_type({expression})" for expression in RESULT_FIELDS]
    lines.append("result.statistics[-1].standard_deviation")
    report = run_mypy("\n".join(lines) + "\n", tmp_path)
    types = revealed(report)
    seen = {e: types.get(i) for i, e in enumerate(RESULT_FIELDS, start=first)}
    assert seen == RESULT_FIELDS, report
    assert '"TableRow" has no attribute "standard_deviation"' in report, report
