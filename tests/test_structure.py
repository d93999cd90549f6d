"""The library's functions stay short enough to read: none outside the command line is longer
than `MAX_LINES` (ruff holds their branches to a complexity of 15 and their statements to 50,
the config in pyproject.toml)."""

from __future__ import annotations

import ast
from pathlib import Path

import nlpcal

PACKAGE = Path(nlpcal.__file__).resolve().parent
#: The most lines of a function's body, its docstring not counted.
MAX_LINES = 80
#: The command line parses and calls: its argument tables are long by nature.
EXEMPT = ("cli",)


def body_lines(function: ast.FunctionDef | ast.AsyncFunctionDef) -> int:
    """Lines from the first statement after the docstring to the function's last line."""
    body = function.body
    first = body[0]
    docstring = (
        isinstance(first, ast.Expr)
        and isinstance(first.value, ast.Constant)
        and isinstance(first.value.value, str)
    )
    if docstring:
        if len(body) == 1:
            return 0
        first = body[1]
    return function.end_lineno - first.lineno + 1


def long_functions(source: str, where: str, limit: int = MAX_LINES) -> list:
    """The "where:line name (N lines)" of every function in `source` whose body exceeds `limit`."""
    found = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            lines = body_lines(node)
            if lines > limit:
                found.append(f"{where}:{node.lineno} {node.name} ({lines} lines)")
    return found


def library_files():
    for path in sorted(PACKAGE.rglob("*.py")):
        if not set(path.relative_to(PACKAGE).parts[:-1]) & set(EXEMPT):
            yield path


def test_no_library_function_is_longer_than_the_limit():
    found = []
    for path in library_files():
        where = str(path.relative_to(PACKAGE.parent))
        found += long_functions(path.read_text(encoding="utf-8"), where)
    assert not found, f"split these into named steps (at most {MAX_LINES} lines each): {found}"


def test_the_length_check_finds_a_long_function_and_skips_its_docstring():
    docstring = '    """' + "\n" * 10 + '    """\n'
    short = "def short():\n" + docstring + "    x = 1\n" * MAX_LINES
    long = "def long():\n" + "    x = 1\n" * (MAX_LINES + 1)
    method = "class A:\n    def method(self):\n" + "        x = 1\n" * (MAX_LINES + 1)
    assert long_functions(short, "m.py") == []
    assert long_functions(long, "m.py") == [f"m.py:1 long ({MAX_LINES + 1} lines)"]
    assert long_functions(method, "m.py") == [f"m.py:2 method ({MAX_LINES + 1} lines)"]


def test_the_command_line_is_exempt_and_everything_else_is_checked():
    checked = {path.relative_to(PACKAGE).parts[0] for path in library_files()}
    assert "cli" not in checked
    assert {"calibration", "nlp", "io", "plots.py"} <= checked
