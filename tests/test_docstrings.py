"""Every public name documents itself in numpydoc form, and its examples run (the doctests of the
API reference, docs/api.md)."""

from __future__ import annotations

import doctest
import inspect
import re
from pathlib import Path

import pytest

import nlpcal

PUBLIC = [name for name in nlpcal.__all__ if name != "__version__"]


def sections(docstring: str) -> set:
    """The numpydoc section headings of a docstring (a line underlined with dashes)."""
    lines = inspect.cleandoc(docstring).splitlines()
    return {
        lines[i].strip()
        for i in range(len(lines) - 1)
        if re.fullmatch(r"-{3,}", lines[i + 1].strip()) and lines[i].strip()
    }


@pytest.mark.parametrize("name", PUBLIC)
def test_every_public_name_has_a_numpydoc_docstring(name):
    value = getattr(nlpcal, name)
    found = sections(value.__doc__ or "")
    assert "Examples" in found, name
    if inspect.isclass(value):  # an exception may carry no more than its message
        assert "Attributes" in found or issubclass(value, Exception), name
    else:
        assert {"Parameters", "Returns", "Raises"} <= found, (name, found)


@pytest.mark.parametrize("name", PUBLIC)
def test_the_examples_run(name):
    value = getattr(nlpcal, name)
    finder = doctest.DocTestFinder(recurse=False)
    tests = [test for test in finder.find(value, name, globs={}) if test.examples]
    assert tests, f"{name} has no example"
    runner = doctest.DocTestRunner(optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE)
    for test in tests:
        runner.run(test)
    assert runner.failures == 0, f"{name}: {runner.failures} example(s) failed (see above)"


def test_the_section_finder_reads_headings():
    doc = """Summary.

    Parameters
    ----------
    x : float
        A value. [nT]

    Examples
    --------
    >>> 1
    1
    """
    assert sections(doc) == {"Parameters", "Examples"}


def test_the_api_reference_documents_every_public_name():
    page = (Path(nlpcal.__file__).resolve().parent.parent / "docs" / "api.md").read_text()
    documented = re.findall(r"^::: nlpcal\.(\w+)$", page, flags=re.MULTILINE)
    assert sorted(documented) == sorted(PUBLIC)
