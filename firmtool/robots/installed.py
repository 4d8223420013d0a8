"""Robot plugins from installed distributions only: no code from the current folder or a scenario's.

A scenario names its robot (``model.robot``), and a robot that is neither built in nor registered
from Python is looked up among the ``firmtool.robots`` entry points. ``importlib.metadata`` finds
entry points in every folder of ``sys.path``, which holds the current folder under ``python -m``
(and a script's folder for a script): a folder someone else prepared, with ``evil.py`` and an
``evil-1.0.dist-info/entry_points.txt`` in it, would make ``python -m firmtool check their.toml`` import
and run ``evil``. So:

- :func:`entry_points` reads the entry points of the distributions installed in the environment's
  site-packages folders (:func:`site_directories`: ``pip install``, ``pip install --user``,
  ``pip install -e``), never of a folder that is only on ``sys.path``;
- :func:`check_origin`, before an entry point is loaded, finds where its module would be imported
  from (without importing it) and refuses a module outside its distribution's installed files (its
  site-packages folder, or the source folder of an editable install): a file of the same name in
  the current folder shadows an installed module on ``sys.path``.

A robot defined in a script is registered from Python (:func:`firmtool.robots.register`), which
needs no entry point.
"""

from __future__ import annotations

import importlib.util
import json
import os
import site
import sys
import sysconfig
from importlib import metadata
from pathlib import Path
from urllib.parse import unquote, urlparse

from firmtool.errors import InputError, quoted


def site_directories() -> tuple[Path, ...]:
    """The environment's site-packages folders (and the user's, when Python reads it), in the
    order of ``sys.path`` (the first distribution of a name found wins, as for imports)."""
    found: list[str] = []
    try:
        found.extend(site.getsitepackages())
    except AttributeError:  # pragma: no cover - a virtualenv without the function
        pass
    if site.ENABLE_USER_SITE:
        found.append(site.getusersitepackages())
    paths = sysconfig.get_paths()
    found.extend(paths[key] for key in ("purelib", "platlib") if key in paths)
    dirs = list(dict.fromkeys(os.path.realpath(d) for d in found if os.path.isdir(d)))
    order = {os.path.realpath(p): i for i, p in reversed(list(enumerate(sys.path))) if p}
    dirs.sort(key=lambda d: order.get(d, len(order)))
    return tuple(Path(d) for d in dirs)


def entry_points(group: str) -> dict[str, metadata.EntryPoint]:
    """Entry points of ``group`` by name, from the distributions installed in :func:`site_directories`
    (the first one of a name wins)."""
    out: dict[str, metadata.EntryPoint] = {}
    seen: set[str] = set()
    for dist in metadata.distributions(path=[str(d) for d in site_directories()]):
        name = (dist.metadata["Name"] or "").lower().replace("_", "-")
        if name in seen:  # a second copy of a distribution, later on the path: not the one installed
            continue
        seen.add(name)
        for ep in dist.entry_points:
            if ep.group == group:
                out.setdefault(ep.name, ep)
    return out


def check_origin(robot: str, ep: metadata.EntryPoint) -> None:
    """Refuse to load ``ep`` if its module would be imported from outside its distribution's files.

    Raises
    ------
    InputError
        One line naming the robot, the entry point and where its module would come from.
    """
    top = ep.module.split(".", 1)[0]
    origins = _origins(top)
    roots = _code_roots(ep.dist) if ep.dist is not None else ()
    outside = [o for o in origins if not any(_inside(o, r) for r in roots)]
    if not origins or outside:
        where = outside[0] if outside else "nowhere"
        raise InputError(f"robot {quoted(robot)}: its entry point {quoted(ep.value)} would import {quoted(top)} from {where}, outside "
                         "the installed distribution that declares it (a module of that name in the current folder "
                         "or on PYTHONPATH shadows it); firmtool runs plugin code only from installed distributions")


def _origins(top: str) -> list[Path]:
    """Where the top-level module ``top`` is (if imported) or would be imported from, without importing it."""
    module = sys.modules.get(top)
    if module is not None:
        file, locations = getattr(module, "__file__", None), list(getattr(module, "__path__", []) or [])
    else:
        try:
            spec = importlib.util.find_spec(top)
        except (ImportError, ValueError):
            return []
        if spec is None:
            return []
        file = spec.origin if spec.has_location else None
        locations = list(spec.submodule_search_locations or [])
    places = [file] if file else locations
    return [Path(os.path.realpath(p)) for p in places if p]


def _code_roots(dist: metadata.Distribution) -> tuple[Path, ...]:
    """Folders a distribution's code is installed in: its site-packages folder and, for an editable
    install, the source folder it records (``direct_url.json``, PEP 610)."""
    roots = []
    try:
        roots.append(Path(os.path.realpath(dist.locate_file(""))))
    except (TypeError, ValueError, NotImplementedError):  # pragma: no cover - a distribution without files
        pass
    try:
        direct = json.loads(dist.read_text("direct_url.json") or "{}")
    except (ValueError, OSError):
        direct = {}
    if isinstance(direct, dict) and isinstance(direct.get("dir_info"), dict) and direct["dir_info"].get("editable"):
        url = urlparse(str(direct.get("url", "")))
        if url.scheme == "file":
            roots.append(Path(os.path.realpath(unquote(url.path))))
    return tuple(roots)


def _inside(path: Path, root: Path) -> bool:
    return path == root or root in path.parents
