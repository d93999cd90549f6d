"""The package as others see it: no import cycle among its modules, and every module or file the
documentation names exists."""

from __future__ import annotations

import ast
import importlib
import re
from pathlib import Path

import nlpcal

PACKAGE = Path(nlpcal.__file__).resolve().parent
ROOT = PACKAGE.parent


def _module_name(path: Path) -> str:
    parts = path.relative_to(ROOT).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


MODULES = {_module_name(path): path for path in sorted(PACKAGE.rglob("*.py"))}


def _never_run(tree: ast.Module) -> set:
    """The nodes under `if TYPE_CHECKING:`: imports for type checkers, never executed."""
    skipped: set = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test):
            for child in node.body:
                skipped.update(id(n) for n in ast.walk(child))
    return skipped


def imported_modules(name: str, source: str):
    """The nlpcal modules an import statement of module `name` names: `from . import passes` is
    nlpcal.passes, `from .errors import InputError` is nlpcal.errors."""
    tree = ast.parse(source)
    skipped = _never_run(tree)
    is_package = MODULES.get(name, Path()).name == "__init__.py"
    package = name.split(".") if is_package else name.split(".")[:-1]
    for node in ast.walk(tree):
        if id(node) in skipped:
            continue
        if isinstance(node, ast.ImportFrom):
            if node.level:
                base = package[: len(package) - (node.level - 1)]
                target = ".".join(base + (node.module.split(".") if node.module else []))
            else:
                target = node.module or ""
            if target.split(".")[0] != "nlpcal":
                continue
            for alias in node.names:
                submodule = f"{target}.{alias.name}"
                yield submodule if submodule in MODULES else target
        elif isinstance(node, ast.Import):
            for alias in node.names:
                if alias.name.split(".")[0] == "nlpcal":
                    yield alias.name


def import_cycles(graph: dict) -> list:
    """The strongly connected components of more than one module (Tarjan), each sorted."""
    index: dict = {}
    low: dict = {}
    stack: list = []
    on_stack: set = set()
    found: list = []

    def visit(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in sorted(graph.get(v, ())):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1 or v in graph.get(v, ()):
                found.append(sorted(component))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return found


def import_graph(sources: dict) -> dict:
    return {name: set(imported_modules(name, text)) for name, text in sources.items()}


def test_no_import_cycle_among_the_modules():
    # Every import statement that runs counts, at module level or inside a function (the command
    # line imports its features late); those under `if TYPE_CHECKING:` never run and do not. A
    # package's __init__ is imported before its submodules, an edge left out here: every
    # package imports its own modules.
    sources = {name: path.read_text() for name, path in MODULES.items()}
    graph = import_graph(sources)
    graph = {name: targets - {name} for name, targets in graph.items()}
    assert import_cycles(graph) == []


def test_the_cycle_check_finds_a_cycle():
    sources = {
        "nlpcal.chunks": "from . import validation\n",
        "nlpcal.validation": "from . import passes\nfrom .errors import InputError\n",
        "nlpcal.passes": "from .chunks import call_threads\n",
        "nlpcal.errors": "",
    }
    assert import_cycles(import_graph(sources)) == [
        ["nlpcal.chunks", "nlpcal.passes", "nlpcal.validation"]
    ]
    typed_only = dict(sources)
    typed_only["nlpcal.passes"] = "if TYPE_CHECKING:\n    from .chunks import call_threads\n"
    assert import_cycles(import_graph(typed_only)) == []


# --- references in the documentation --------------------------------------------------------------

DOCUMENTS = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
PATH = re.compile(r"\bnlpcal/[\w/]*\w(?:\.py)?")
DOTTED = re.compile(r"\bnlpcal(?:\.[A-Za-z_]\w*)+")


def _resolves(dotted: str) -> bool:
    """A module, or an attribute chain of the longest module prefix of it."""
    parts = dotted.split(".")
    for i in range(len(parts), 0, -1):
        try:
            value = importlib.import_module(".".join(parts[:i]))
        except ImportError:
            continue
        for attribute in parts[i:]:
            if not hasattr(value, attribute):
                return False
            value = getattr(value, attribute)
        return True
    return False


def stale_references(texts: dict) -> list:
    """(where, reference) for every nlpcal/... path and nlpcal.x.y name that does not exist."""
    stale = []
    for where, text in texts.items():
        for match in PATH.finditer(text):
            path = ROOT / match.group(0)
            if not (path.exists() or path.with_suffix(".py").exists()):
                stale.append((where, match.group(0)))
        names = (match.group(0) for match in DOTTED.finditer(text))
        stale.extend((where, name) for name in names if not _resolves(name))
    return stale


def test_every_module_and_file_the_documents_and_docstrings_name_exists():
    texts = {str(path.relative_to(ROOT)): path.read_text() for path in DOCUMENTS}
    texts.update({str(path.relative_to(ROOT)): path.read_text() for path in MODULES.values()})
    assert stale_references(texts) == []


def test_the_reference_check_finds_a_stale_name():
    text = "see `nlpcal/compass.py` and `nlpcal.problems.objective_function`; `nlpcal.calibrate`"
    assert stale_references({"page": text}) == [
        ("page", "nlpcal/compass.py"),
        ("page", "nlpcal.problems.objective_function"),
    ]


# --- release metadata ---------------------------------------------------------------------------


def requirement_floors(pyproject: str) -> dict:
    """package -> the set of floors (>=X) that the dependencies and extras ask of it."""
    floors: dict = {}
    for name, floor in re.findall(r'"([A-Za-z0-9_.-]+)(?:\[[^\]]*\])?>=([^",<]+)', pyproject):
        floors.setdefault(name.lower(), set()).add(floor)
    return floors


def test_every_extra_asks_the_same_floor_of_a_package():
    floors = requirement_floors((ROOT / "pyproject.toml").read_text())
    assert {name: found for name, found in floors.items() if len(found) > 1} == {}
    assert requirement_floors('a = ["pyarrow>=10"]\nb = ["pyarrow>=14", "dask[array]>=1"]') == {
        "pyarrow": {"10", "14"},
        "dask": {"1"},
    }


def test_the_citation_names_this_version():
    citation = (ROOT / "CITATION.cff").read_text()
    assert re.search(r"^cff-version: 1\.2\.0$", citation, flags=re.MULTILINE)
    assert re.findall(r"^version: (\S+)$", citation, flags=re.MULTILINE) == [nlpcal.__version__]
