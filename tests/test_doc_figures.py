"""The documentation's figures are made with the numbers the code ships (issue 42, 3): each figure
`firmtool plot` drew for the docs carries its provenance (the scenario's hash, the engine's version),
which must match the shipped scenario and this engine. A change that moves the numbers (an engine
version, an edited scenario) fails here until `python docs/make_figures.py` has redrawn them."""

import importlib.util
import sys

import pytest
from conftest import ROOT

from firmtool.estimation.edge_table import ENGINE_VERSION
from firmtool.io.figure_file import png_text
from firmtool.scenario import load_scenario

spec = importlib.util.spec_from_file_location("make_figures", ROOT / "docs" / "make_figures.py")
make_figures = importlib.util.module_from_spec(spec)
sys.modules["make_figures"] = make_figures  # its dataclasses look their module up
spec.loader.exec_module(make_figures)
PLOTTED = [f for f in make_figures.FIGURES if f.command.startswith("firmtool plot ")]


@pytest.mark.parametrize("figure", PLOTTED, ids=[f.file for f in PLOTTED])
def test_a_docs_figure_was_drawn_from_the_shipped_scenario_by_this_engine(figure):
    text = png_text((ROOT / "docs" / "figures" / figure.file).read_bytes())
    name = text.get("firmtool:scenario")
    assert name, f"{figure.file}: no provenance; redraw it: python docs/make_figures.py {figure.file[:-4]}"
    shipped = load_scenario(ROOT / "scenarios" / f"{name}.toml")
    assert text.get("firmtool:engine_version") == str(ENGINE_VERSION), \
        f"{figure.file}: drawn by engine version {text.get('firmtool:engine_version')}, this one is {ENGINE_VERSION}"
    assert text.get("firmtool:scenario_sha256") == shipped.sha256, \
        f"{figure.file}: drawn from another text of scenarios/{name}.toml: python docs/make_figures.py {name}"


def test_provenance_is_written_by_plot(smoke_roadmap, tmp_path):
    from typer.testing import CliRunner

    from firmtool.cli import app

    out = tmp_path / "fig.png"
    r = CliRunner().invoke(app, ["plot", str(smoke_roadmap[0]), "-o", str(out), "--episodes", "2", "--seed", "3",
                                 "--dpi", "40"])
    assert r.exit_code == 0, r.output
    text = png_text(out.read_bytes())
    assert text["firmtool:scenario"] == "smoke" and text["firmtool:engine_version"] == str(ENGINE_VERSION)
    assert text["firmtool:scenario_sha256"] == load_scenario(ROOT / "scenarios" / "smoke.toml").sha256
    assert text["firmtool:episodes"] == "2 episodes, seed 3"
