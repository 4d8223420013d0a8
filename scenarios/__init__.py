"""The shipped scenarios (``*.toml``), installed with firmtool as the package ``firmtool.scenarios``
(setup.py maps this folder onto it), so that a shipped scenario can be named from any folder:
``firmtool run arm8_lightdark``, ``load_scenario("smoke")``. See :func:`firmtool.scenario.shipped_scenarios`.
"""
