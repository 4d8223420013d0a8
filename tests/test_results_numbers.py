"""The results pages' numbers are what their commands give (issue 54, 6): each measurement of
``docs/results/numbers.json`` is run again at its reduced size (the same code path: build, solve,
execute, seeds kept) and must give exactly the recorded numbers; the pages are written from that
file (``docs/generate.py``, checked current by tests/test_generated_docs.py), stamped with the
version and commit that measured them."""

from __future__ import annotations

import importlib.util

import pytest
from conftest import ROOT


def _module():
    spec = importlib.util.spec_from_file_location("docs_results_numbers", ROOT / "docs" / "results_numbers.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


results_numbers = _module()


@pytest.mark.parametrize("name", sorted(results_numbers.recorded()))
def test_a_results_pages_numbers_are_what_its_command_gives(name):
    recorded = results_numbers.recorded()[name]
    assert recorded["version"] and recorded["commit"]  # stamped
    again = results_numbers.measure(name, reduced=True, workers=1)  # the workers change no number
    for key in results_numbers.COMPARED:
        assert again[key] == recorded["reduced"][key], (
            f"{name}: {key} is {again[key]} now, {recorded['reduced'][key]} recorded: the code moved the results "
            f"page's numbers; measure them again (python docs/results_numbers.py {name}) and read the page")


def test_every_generated_results_block_names_a_recorded_measurement():
    pages = sorted((ROOT / "docs" / "results").glob("*.md"))
    names = {n for p in pages for line in p.read_text().splitlines()
             if line.startswith("<!-- generated: results ") for n in line.split()[3:-1]}
    assert names and names <= set(results_numbers.recorded()) <= set(results_numbers.MEASUREMENTS)
