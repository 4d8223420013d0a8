"""The corpus of untrusted inputs (issue 35): roadmaps, scenarios and folders someone else prepared.

Every case is made by code here, in a fresh folder, from the built smoke roadmap or the smoke
scenario (no binary file is committed): the generator is the corpus. A case names its class, makes
its files, and says which command opens them and what must come of it: refused (exit 2, one line
naming the object or field) or handled (exit 0). ``tests/test_untrusted.py`` runs each one in a
child process with a 20 s timeout, and checks that nothing outside the case's files was read (the
files a case points at but must not be read are FIFOs: reading one would block until the timeout),
that no planted code ran (a marker file), and that no file but firmtool's own outputs changed.

Classes (``Case.klass``):

- ``hdf5``: objects stored outside the roadmap (external links, soft links and their cycles, virtual
  datasets, external storage) and sizes declared far beyond what is stored;
- ``lock``: the writer lock's sidecar planted as a symlink, a hard link, a FIFO, a folder, another
  user's file or a file with other content;
- ``mesh``: a mesh obstacle's side file that is a device, a FIFO, huge, too fine, or holds a secret,
  in a scenario and in the scenario text a roadmap stores;
- ``budget``: work far beyond what a build, a design or an execution may take;
- ``attribute``: stage attributes missing, NaN, arrays, bogus texts;
- ``option``: command-line values that reach a library call unchecked;
- ``table``: derived tables rewritten consistently enough to pass the shape checks (issue 52): swept
  regions (inverted, shrunk to a point, moved away, non-finite, of another world's dimension), step
  histograms (moved between outcomes or steps with the per-edge sums kept, beyond an edge's steps),
  the time-indexed policy's attributes against its arrays; each must be refused, never read into a
  silently wrong probability or update;
- ``side``: side files a command reads besides the roadmap: ``--task`` files that are FIFOs,
  devices, huge, nested deep or not text, and stored query images declared far larger than stored;
- ``deadline``: deadlines beyond the roadmap's budget (CLI and scenario);
- ``message``: values echoed in messages (long names, names HDF5 cannot hold), messages that must
  blame the right thing.

The plugin, argument, stamp and disk-full classes need a process of their own or the API and are
made in the test module.
"""

from __future__ import annotations

import hashlib
import os
import shutil
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import h5py
import numpy as np
from conftest import room_3d

ROOT = Path(__file__).resolve().parents[1]
SMOKE = ROOT / "scenarios" / "smoke.toml"
SECRET = "api_key=sk-live-5f3c9a1e"  # a secret a crafted side file holds: no message may show it


@dataclass(frozen=True)
class Case:
    """One untrusted input.

    name : unique, for the test id.
    klass : the class (see the module's docstring).
    make : ``make(folder, roadmap) -> argv``: writes the case's files into ``folder`` (``roadmap``
        is a copy of the solved smoke roadmap there, ``folder / "r.h5"``) and returns the firmtool
        command line that opens them.
    phrases : what the one error line must hold (the object or field it names); empty for a case
        that is handled (exit 0).
    code : the exit code (2 refused, 0 handled).
    outputs : names in ``folder`` that the command may create or change (firmtool's own outputs).
    """

    name: str
    klass: str
    make: Callable[[Path, Path], list[str]]
    phrases: tuple[str, ...] = ()
    code: int = 2
    outputs: tuple[str, ...] = field(default=(".r.h5.lock",))


# -- helpers -----------------------------------------------------------------------------------------

def edit(roadmap: Path, fn: Callable[[h5py.File], None]) -> None:
    with h5py.File(roadmap, "r+") as f:
        fn(f)


def fifo(folder: Path, name: str) -> Path:
    """A FIFO nobody writes to: a reader that opens it blocks (the canary of 'nothing outside read')."""
    path = folder / name
    os.mkfifo(path)
    return path


def _args(command: str, roadmap: Path) -> list[str]:
    return [command, str(roadmap)] + (["-n", "2"] if command == "execute" else [])


def external_link(stage: str, command: str, phrase: str | None = None) -> Case:
    """``/stage`` (or a dataset) replaced by an external link into a FIFO posing as an HDF5 file."""
    def make(folder: Path, roadmap: Path) -> list[str]:
        target = fifo(folder, "other.h5")
        edit(roadmap, lambda f: (f.__delitem__(stage), f.__setitem__(stage, h5py.ExternalLink(str(target), "/x"))))
        return _args(command, roadmap)
    return Case(f"external_link_{stage.replace('/', '_')}_{command}", "hdf5", make,
                (f"'/{stage}' is an external link", phrase or "stored in the file itself"))


def soft_link(stage: str, to: str, command: str) -> Case:
    def make(folder: Path, roadmap: Path) -> list[str]:
        def fn(f: h5py.File) -> None:
            if to != stage and to not in f:
                f.copy(f[stage], to)
            del f[stage]
            f[stage] = h5py.SoftLink(f"/{to}")
        edit(roadmap, fn)
        return _args(command, roadmap)
    kind = "cycle" if to == stage else "link"
    return Case(f"soft_{kind}_{stage.replace('/', '_')}_{command}", "hdf5", make, (f"'/{stage}' is a soft link",))


def external_storage(dataset: str, target: str, command: str) -> Case:
    """A dataset whose raw bytes are stored in another file (``external=``): a FIFO, a device or a
    file of the system."""
    def make(folder: Path, roadmap: Path) -> list[str]:
        where = str(fifo(folder, "storage")) if target == "fifo" else target

        def fn(f: h5py.File) -> None:
            old = f[dataset]
            shape, dtype = old.shape, old.dtype
            del f[dataset]
            size = int(np.prod(shape)) * dtype.itemsize
            f.create_dataset(dataset, shape=shape, dtype=dtype, external=[(where, 0, size)])
        edit(roadmap, fn)
        return _args(command, roadmap)
    label = target.strip("/").replace("/", "_")
    return Case(f"external_storage_{dataset.replace('/', '_')}_{label}_{command}", "hdf5", make,
                (f"'/{dataset}' keeps its data in external storage",))


def virtual_dataset(dataset: str, command: str) -> Case:
    """A virtual dataset mapping a dataset of another file (a FIFO posing as one)."""
    def make(folder: Path, roadmap: Path) -> list[str]:
        source = fifo(folder, "source.h5")

        def fn(f: h5py.File) -> None:
            old = f[dataset]
            layout = h5py.VirtualLayout(shape=old.shape, dtype=old.dtype)
            layout[...] = h5py.VirtualSource(str(source), "data", shape=old.shape, dtype=old.dtype)
            del f[dataset]
            f.create_virtual_dataset(dataset, layout)
        edit(roadmap, fn)
        return _args(command, roadmap)
    return Case(f"virtual_{dataset.replace('/', '_')}_{command}", "hdf5", make, (f"'/{dataset}' is a virtual dataset",))


def huge_declared(dataset: str, shape: tuple[int, ...], dtype: str, command: str, phrase: str) -> Case:
    """A dataset declared huge but never written (chunked, compressed: a file of kilobytes)."""
    def make(folder: Path, roadmap: Path) -> list[str]:
        def fn(f: h5py.File) -> None:
            if dataset in f:
                del f[dataset]
            f.create_dataset(dataset, shape=shape, dtype=dtype, chunks=(min(shape[0], 2**20),) + shape[1:],
                             compression="gzip", fillvalue=0)
        edit(roadmap, fn)
        return _args(command, roadmap)
    return Case(f"huge_{dataset.replace('/', '_')}_{dtype}_{command}", "hdf5", make, (f"'/{dataset}'", phrase))


def reference_attribute(command: str) -> Case:
    """A root attribute holding an object reference (what another file's reader might follow)."""
    def make(folder: Path, roadmap: Path) -> list[str]:
        edit(roadmap, lambda f: f.attrs.__setitem__("created", f["nodes"].ref))
        return _args(command, roadmap)
    return Case(f"reference_attribute_{command}", "hdf5", make, ("attribute 'created' of '/'", "not numbers or text"))


def roadmap_is_fifo(command: str) -> Case:
    def make(folder: Path, roadmap: Path) -> list[str]:
        roadmap.unlink()
        fifo(folder, roadmap.name)
        return _args(command, roadmap)
    return Case(f"roadmap_is_a_fifo_{command}", "hdf5", make, ("not a regular file",))


def cache_link(command: str, code: int, phrase: tuple[str, ...]) -> Case:
    """An external link in the optional ``/edge_cache``: a reader ignores it (it only saves work),
    a rewrite refuses to carry it over."""
    def make(folder: Path, roadmap: Path) -> list[str]:
        target = fifo(folder, "cache.h5")

        def fn(f: h5py.File) -> None:
            if "edge_cache" in f:
                del f["edge_cache"]
            f["edge_cache"] = h5py.ExternalLink(str(target), "/edges")
        edit(roadmap, fn)
        return _args(command, roadmap)
    return Case(f"external_link_edge_cache_{command}", "hdf5", make, phrase, code=code)


def foreign_group_link(command: str) -> Case:
    """A group firmtool does not know, holding an external link: a rewrite would copy it."""
    def make(folder: Path, roadmap: Path) -> list[str]:
        target = fifo(folder, "notes.h5")

        def fn(f: h5py.File) -> None:
            g = f.create_group("notes")
            g["more"] = h5py.ExternalLink(str(target), "/x")
        edit(roadmap, fn)
        return [command, str(roadmap), "--failure-cost", "50"]
    return Case(f"foreign_group_external_link_{command}", "hdf5", make, ("'/notes/more' is an external link",))


def foreign_group(kind: str, command: str, phrase: str) -> Case:
    """A group firmtool does not know (a rewrite copies it): too many members, or datasets each within
    the bound but too large together (declared, never written: a small file)."""
    def make(folder: Path, roadmap: Path) -> list[str]:
        def fn(f: h5py.File) -> None:
            g = f.create_group("notes")
            if kind == "members":
                for i in range(300):
                    g[f"n{i}"] = np.zeros(1)
            else:
                for name in ("a", "b"):
                    g.create_dataset(name, shape=(2**27,), dtype="f8", chunks=(2**20,), compression="gzip")
        edit(roadmap, fn)
        return [command, str(roadmap), "--failure-cost", "50"]
    return Case(f"foreign_group_{kind}_{command}", "hdf5", make, ("'/notes", phrase))


def crafted_map(kind: str, command: str, phrase: str) -> Case:
    """A ``/map`` (the occupancy map a roadmap carries, firmtool.io.roadmap_map) crafted: an external
    link, or a shape declared beyond the cap (refused before anything is read)."""
    def make(folder: Path, roadmap: Path) -> list[str]:
        target = fifo(folder, "map.h5")

        def fn(f: h5py.File) -> None:
            if kind == "link":
                f["map"] = h5py.ExternalLink(str(target), "/map")
                return
            g = f.create_group("map")
            g.attrs["shape"] = np.array([2**20, 2**20], dtype=np.int64)
            g.create_dataset("occupied", shape=(2**37,), dtype="u1", chunks=(2**20,), compression="gzip")
        edit(roadmap, fn)
        return _args(command, roadmap)
    return Case(f"crafted_map_{kind}_{command}", "hdf5", make, ("'/map", phrase))


def hdf5_cases() -> list[Case]:
    cases = [external_link(stage, command) for stage, command in
             (("edges", "inspect"), ("edges", "solve"), ("nodes", "design"), ("policy", "execute"),
              ("controllers", "estimate"), ("edges/key", "inspect"), ("nodes/centers", "solve"))]
    cases += [soft_link("policy", "policy", "execute"), soft_link("policy", "policy", "inspect"),
              soft_link("edges", "edges_copy", "solve"), soft_link("nodes/centers", "centers_copy", "inspect")]
    cases += [external_storage("edges/key", "/etc/passwd", "solve"), external_storage("edges/key", "fifo", "inspect"),
              external_storage("nodes/centers", "/dev/zero", "execute"),
              external_storage("edges/cost_mean", "fifo", "estimate"),
              external_storage("policy/edge", "/etc/hostname", "execute")]
    cases += [virtual_dataset("nodes/centers", "inspect"), virtual_dataset("edges/outcome_count", "solve")]
    cases += [huge_declared("nodes/centers", (2**26, 12), "i1", "inspect", "to check"),
              huge_declared("edges/extra", (3 * 2**28,), "i1", "solve", "to check"),
              huge_declared("policy/extra", (2**31,), "f8", "execute", "to read")]
    cases += [reference_attribute("inspect"), reference_attribute("solve")]
    cases += [roadmap_is_fifo(c) for c in ("inspect", "execute", "solve", "design", "estimate", "plot")]
    cases += [cache_link("inspect", 0, ()), cache_link("solve", 2, ("'/edge_cache' is an external link",)),
              foreign_group_link("solve"), foreign_group("members", "solve", "more than 256 members"),
              foreign_group("large", "solve", "too large to copy")]
    cases += [crafted_map("link", "inspect", "external link"), crafted_map("shape", "solve", "cells a side")]
    return cases


# -- the writer lock -------------------------------------------------------------------------------------

IMPORTANT = "important.txt"


def lock(kind: str, command: str = "solve") -> Case:
    """The lock sidecar ``.r.h5.lock`` planted before a writer runs."""
    def make(folder: Path, roadmap: Path) -> list[str]:
        important = folder / IMPORTANT
        important.write_text("the user's own data\n")
        lp = folder / ".r.h5.lock"
        if kind == "symlink":
            lp.symlink_to(important)
        elif kind == "dangling_symlink":
            lp.symlink_to(folder / "created_through_the_link")
        elif kind == "hard_link":
            os.link(important, lp)
        elif kind == "fifo":
            os.mkfifo(lp)
        elif kind == "folder":
            lp.mkdir()
        elif kind == "other_user":
            lp.write_text("")
            os.chown(lp, 65534, 65534)  # needs root: the test skips this case otherwise
        elif kind == "other_content":
            lp.write_text(SECRET + "\n")
        elif kind == "stale_pid":
            lp.write_text("999999\n")
        if command == "sample":
            return ["sample", str(SMOKE), "-o", str(roadmap)]
        return [command, str(roadmap)] + (["--failure-cost", "50"] if command == "solve" else [])
    why = {"symlink": "is a symbolic link", "dangling_symlink": "is a symbolic link", "hard_link": "has other names",
           "fifo": "is not a regular file", "folder": "is a folder", "other_user": "belongs to another user",
           "other_content": "holds something other than a process id"}
    if kind == "stale_pid":  # a lock file of ours left by a process that is gone: used, not refused
        return Case(f"lock_{kind}_{command}", "lock", make, (), code=0, outputs=(".r.h5.lock", "r.h5"))
    return Case(f"lock_{kind}_{command}", "lock", make, (".r.h5.lock", why[kind]), outputs=())


def lock_cases() -> list[Case]:
    cases = [lock(kind) for kind in ("symlink", "dangling_symlink", "hard_link", "fifo", "folder", "other_user",
                                     "other_content", "stale_pid")]
    cases += [lock("symlink", command) for command in ("design", "estimate", "sample")]
    return cases


# -- mesh side files -------------------------------------------------------------------------------------

def _room(file: str) -> str:
    """The 3-D room whose one obstacle is the mesh ``file``."""
    return room_3d(f'{{ kind = "mesh", file = "{file}" }}')


CUBE = ("v 2 2 2\nv 3 2 2\nv 3 3 2\nv 2 3 2\nv 2 2 3\nv 3 2 3\nv 3 3 3\nv 2 3 3\n"
        "f 1 3 2\nf 1 4 3\nf 5 6 7\nf 5 7 8\nf 1 2 6\nf 1 6 5\nf 2 3 7\nf 2 7 6\nf 3 4 8\nf 3 8 7\nf 4 1 5\nf 4 5 8\n")


def _mesh_file(folder: Path, kind: str) -> str:
    """The mesh file of a case, made in ``folder``; returns the name the scenario gives."""
    if kind in ("/dev/zero", "/dev/urandom", "/etc/passwd"):
        return kind
    path = folder / "mesh.obj"
    if kind == "fifo":
        os.mkfifo(path)
    elif kind == "folder":
        path.mkdir()
    elif kind == "too_large":
        with open(path, "wb") as fh:  # sparse: 17 MiB declared, nothing stored
            fh.truncate(17 * 2**20)
    elif kind == "too_many_vertices":
        path.write_text("v 0 0 0\n" * 100_001 + "f 1 2 3\n")
    elif kind == "too_many_triangles":
        path.write_text("v 2 2 2\nv 3 2 2\nv 3 3 2\n" + "f 1 2 3\n" * 200_001)
    elif kind == "secret":
        path.write_text(CUBE + f"v {SECRET} 0 0\n")
    elif kind == "secret_face":
        path.write_text(CUBE + f"f {SECRET} 1 2\n")
    elif kind == "binary":
        path.write_bytes(b"v 0 0 0\n\xff\xfe\x00" + SECRET.encode())
    elif kind == "link_outside":
        path.symlink_to("/etc/passwd")
    elif kind == "good":
        path.write_text(CUBE)
    return path.name


def mesh(kind: str, phrase: str) -> Case:
    """A scenario whose mesh obstacle names a side file of ``kind``; ``firmtool check`` opens it."""
    def make(folder: Path, roadmap: Path) -> list[str]:
        scenario = folder / "room.toml"
        scenario.write_text(_room(_mesh_file(folder, kind)))
        return ["check", str(scenario)]
    return Case(f"mesh_{kind.strip('/').replace('/', '_')}", "mesh", make, ("world.obstacles[0].file", phrase))


def stored_mesh(kind: str, name: str | None, phrase: str) -> Case:
    """The scenario text stored in a roadmap names a mesh file (``inspect`` parses it first)."""
    def make(folder: Path, roadmap: Path) -> list[str]:
        file = name if name is not None else _mesh_file(folder, kind)
        text = _room(file)

        def fn(f: h5py.File) -> None:
            f.attrs["scenario_toml"] = text
            f.attrs["scenario_sha256"] = hashlib.sha256(text.encode()).hexdigest()
        edit(roadmap, fn)
        return ["inspect", str(roadmap)]
    return Case(f"stored_mesh_{kind}", "mesh", make, ("scenario_toml: world.obstacles[0].file", phrase))


def mesh_cases() -> list[Case]:
    cases = [mesh("/dev/zero", "found a character device"), mesh("/dev/urandom", "found a character device"),
             mesh("fifo", "found a FIFO"), mesh("folder", "it is a directory"),
             mesh("too_large", "at most 16 MiB"), mesh("too_many_vertices", "at most 100000 vertices"),
             mesh("too_many_triangles", "at most 200000 triangles"), mesh("secret", "line 21"),
             mesh("secret_face", "line 21"), mesh("binary", "not UTF-8")]
    cases += [stored_mesh("absolute", "/etc/passwd", "only inside the roadmap's folder"),
              stored_mesh("device", "/dev/zero", "only inside the roadmap's folder"),
              stored_mesh("parent", "../secret.obj", "only inside the roadmap's folder"),
              stored_mesh("link_outside", None, "leads outside it through a link"),
              stored_mesh("fifo", None, "found a FIFO")]
    return cases


# -- budgets ---------------------------------------------------------------------------------------------

def scenario_text(**replace: str) -> str:
    text = SMOKE.read_text()
    for old, new in replace.items():
        assert old in text, old
        text = text.replace(old, new)
    return text


def scenario_case(name: str, klass: str, text: str, command: str, phrases: tuple[str, ...]) -> Case:
    def make(folder: Path, roadmap: Path) -> list[str]:
        path = folder / f"{name}.toml"
        path.write_text(text)
        return [command, str(path)] + (["-o", str(folder / "out.h5")] if command in ("build", "sample") else [])
    return Case(name, klass, make, phrases, outputs=(".out.h5.lock",))


def many_nodes_file(count: int) -> Callable[[Path, Path], list[str]]:
    """The roadmap with ``count`` valid sampled nodes and no later stage: ``design`` opens it."""
    def make(folder: Path, roadmap: Path) -> list[str]:
        rng = np.random.default_rng(0)
        # the smoke world: 4 x 3 with one box at (2.0, 1.2) half size (0.3, 0.7), robot radius 0.08
        pts = rng.uniform([0.1, 0.1], [3.9, 2.9], size=(2 * count, 2))
        clear = (np.abs(pts[:, 0] - 2.0) > 0.45) | (np.abs(pts[:, 1] - 1.2) > 0.85)
        pts = pts[clear][:count]

        def fn(f: h5py.File) -> None:
            centers, kind = f["nodes/centers"][()], f["nodes/kind"][()]
            for stage in ("policy", "edges", "controllers", "edge_cache"):
                if stage in f:
                    del f[stage]
            del f["nodes/centers"], f["nodes/kind"]
            f["nodes/centers"] = np.concatenate([centers[:2], pts])
            f["nodes/kind"] = np.concatenate([kind[:2], np.zeros(pts.shape[0], dtype=kind.dtype)])
        edit(roadmap, fn)
        return ["design", str(roadmap)]
    return make


def budget_cases() -> list[Case]:
    return [
        scenario_case("nodes_200000_one_particle", "budget",
                      scenario_text(**{"nodes = 10": "nodes = 200000", "particles = 100": "particles = 1"}), "check",
                      ("roadmap.nodes", "expected at most 58 nodes")),
        scenario_case("nodes_300000_no_separation", "budget",
                      scenario_text(**{"nodes = 10": "nodes = 300000", "min_separation = 0.6": "min_separation = 0.0",
                                       "particles = 100": "particles = 1"}), "check",
                      ("roadmap.nodes", "sampling and designing 300000 nodes")),
        scenario_case("nodes_200000_build", "budget",
                      scenario_text(**{"nodes = 10": "nodes = 200000", "particles = 100": "particles = 1"}), "build",
                      ("roadmap.nodes",)),
        scenario_case("dt_1e12", "budget", scenario_text(**{"dt = 0.1": "dt = 1e12"}), "check", ("model.dt",)),
        scenario_case("dt_1e12_build", "budget", scenario_text(**{"dt = 0.1": "dt = 1e12"}), "build", ("model.dt",)),
        scenario_case("dt_10", "budget", scenario_text(**{"dt = 0.1": "dt = 10.0"}), "check", ("model.dt",)),
        Case("roadmap_file_of_1e6_nodes", "budget", many_nodes_file(10**6), ("'/nodes/centers' holds", "nodes")),
        Case("push_1e7", "budget", lambda folder, roadmap: ["execute", str(roadmap), "-n", "2", "-d", "push:10:1e7"],
             ("--disturbance", "SIZE")),
        Case("push_1e20", "budget", lambda folder, roadmap: ["execute", str(roadmap), "-n", "2", "-d", "push:10:1e20"],
             ("--disturbance", "SIZE")),
        Case("push_random_1e7", "budget",
             lambda folder, roadmap: ["execute", str(roadmap), "-n", "2", "-d", "push:random:1e7:0.5"],
             ("--disturbance", "SIZE")),
        Case("push_1e7_no_replan", "budget", lambda folder, roadmap: ["execute", str(roadmap), "-n", "1", "--no-replan",
                                                                 "-d", "push:0:1e7"], ("--disturbance",)),
    ]


# -- stage attributes ------------------------------------------------------------------------------------

def attribute(group: str, key: str, value: object, command: str = "inspect") -> Case:
    """An attribute of ``group`` set to ``value`` (None: deleted)."""
    def make(folder: Path, roadmap: Path) -> list[str]:
        def fn(f: h5py.File) -> None:
            attrs = f[group].attrs if group != "/" else f.attrs
            if value is None:
                del attrs[key]
            else:
                attrs[key] = value
        edit(roadmap, fn)
        return _args(command, roadmap)
    label = "missing" if value is None else type(value).__name__ if not isinstance(value, float) else repr(value)
    where = f"'/{group.strip('/')}'" if group != "/" else "'/'"
    return Case(f"attr_{group.strip('/') or 'root'}_{key}_{label}_{command}".replace(".", "_"), "attribute", make,
                (f"attribute '{key}' of {where}",))


def attribute_cases() -> list[Case]:
    nan, arr = float("nan"), np.arange(3)
    return [
        attribute("policy", "status", None, "execute"), attribute("policy", "status", "BOGUS", "execute"),
        attribute("policy", "status", nan), attribute("policy", "status", arr, "execute"),
        attribute("policy", "iterations", None, "execute"), attribute("policy", "iterations", nan),
        attribute("policy", "iterations", -1), attribute("policy", "iterations", arr),
        attribute("policy", "iterations", "many", "execute"), attribute("policy", "iterations", 2.5),
        attribute("policy", "residual", None, "execute"), attribute("policy", "residual", "small"),
        attribute("policy", "residual", nan, "execute"), attribute("policy", "residual", -1.0),
        attribute("policy", "method", None, "execute"), attribute("policy", "method", "newton"),
        attribute("policy", "method", 5), attribute("policy", "failure_cost", None, "execute"),
        attribute("policy", "failure_cost", "100"), attribute("policy", "interval_samples", 0),
        attribute("nodes", "densify_rounds", nan), attribute("nodes", "densify_rounds", arr),
        attribute("nodes", "densify_rounds", "two"), attribute("nodes", "densify_rounds", -1, "solve"),
        attribute("nodes", "connect_budget", nan), attribute("nodes", "connect_budget", "x", "execute"),
        attribute("nodes", "connect_added", -1), attribute("nodes", "connect_stop_reason", 5),
        attribute("nodes", "validity_checker", arr, "solve"), attribute("nodes", "goals", "x"),
        attribute("edges", "inputs_sha256", None, "solve"), attribute("edges", "inputs_sha256", 5, "solve"),
        attribute("edges", "inputs_sha256", arr), attribute("edges", "seed", -1),
        attribute("edges", "failed_edges", "x"), attribute("controllers", "node_radius", "wide"),
        attribute("controllers", "node_radius", -1.0, "execute"), attribute("controllers", "covariance_tolerance", nan),
        attribute("nodes", "scenario_sha256", arr, "execute"), attribute("/", "created", arr),
        attribute("/", "firmtool_version", 7, "solve"),
    ]


# -- options ---------------------------------------------------------------------------------------------

def option_cases() -> list[Case]:
    return [
        Case("scheduler_not_a_url_estimate", "option",
             lambda folder, roadmap: ["estimate", str(roadmap), "--executor", "dask", "--scheduler", "not a url"],
             ("--scheduler", "not a url")),
        Case("scheduler_port_out_of_range_build", "option",
             lambda folder, roadmap: ["build", str(SMOKE), "-o", str(folder / "b.h5"), "--executor", "dask",
                                      "--scheduler", "tcp://host:99999"], ("--scheduler",)),
    ]


# -- derived tables (issue 52) ----------------------------------------------------------------------------

def _rewrite(f: h5py.File, name: str, value: np.ndarray) -> None:
    """Replace dataset ``name`` by ``value`` (any shape: a new dataset of the same dtype kind)."""
    dtype = f[name].dtype
    del f[name]
    f[name] = np.asarray(value).astype(dtype)


def table(name: str, fn: Callable[[h5py.File], None], command: str, phrases: tuple[str, ...],
          extra: tuple[str, ...] = ()) -> Case:
    """A derived table of the solved smoke roadmap rewritten by ``fn``; ``command`` opens it."""
    def make(folder: Path, roadmap: Path) -> list[str]:
        edit(roadmap, fn)
        if command == "update":
            path = folder / "moved.toml"
            path.write_text(scenario_text(**{"center = [2.0, 1.2]": "center = [2.0, 1.3]"}))
            return ["update", str(roadmap), str(path)]
        return [command, str(roadmap), *extra] + (["-n", "2"] if command == "execute" else [])
    return Case(f"table_{name}_{command}", "table", make, phrases)


def _swept(kind: str) -> Callable[[h5py.File], None]:
    def fn(f: h5py.File) -> None:
        lo, hi = f["edges/swept_lo"][()], f["edges/swept_hi"][()]
        if kind == "inverted":
            lo, hi = hi, lo
        elif kind == "point":  # shrunk to one corner (lo == hi): far from most sources' key points
            hi = lo.copy()
        elif kind == "inf":
            lo[0, 0] = -np.inf
        elif kind == "nan":
            hi[-1, 1] = np.nan
        elif kind == "moved":  # the same boxes, moved far off (outside the world)
            lo, hi = lo + 50.0, hi + 50.0
        elif kind == "one_row_inverted":
            lo[3], hi[3] = hi[3].copy(), lo[3].copy()
        elif kind == "third_dim":  # (E, 3) in the 2-D world
            lo, hi = np.c_[lo, np.zeros(len(lo))], np.c_[hi, np.ones(len(hi))]
        elif kind == "huge":
            lo[:] = -1e300
            hi[:] = 1e300
        _rewrite(f, "edges/swept_lo", lo)
        _rewrite(f, "edges/swept_hi", hi)
    return fn


def _steps(kind: str, consistent: bool = True) -> Callable[[h5py.File], None]:
    """The step histograms rewritten; with ``consistent``, ``particle_steps``, ``steps_mean`` and the
    cost's steps term made to agree with them (what a careful forger does), so that only the checks
    against the edges' own steps can tell."""
    def fn(f: h5py.File) -> None:
        e = f["edges"]
        edge, code, value, count = (e[f"steps_{n}"][()] for n in ("edge", "code", "value", "count"))
        if kind == "all_in_one_step":  # every particle in 1 step, per-edge and per-outcome sums kept
            value[:] = 1
        elif kind == "moved_outcome":  # a failure's particles moved to a landing, per-edge sums kept
            land = np.flatnonzero(code >= 0)
            fail = np.flatnonzero((code < 0) & np.isin(edge, edge[land]))
            r = int(fail[0])
            same = land[edge[land] == edge[r]][0]
            code[r] = code[same]
        elif kind == "beyond_max_steps":
            value[np.argmax(value)] = 2**31 - 1
        elif kind == "just_beyond":
            value[np.argmax(value)] = 400  # the smoke edges run at most 150 steps past their nominal (<= 30)
        elif kind == "goal_in_one_step":  # landings in the goal node (which a goal ball may reach early) in 1 step
            value[code == 1] = 1
        elif kind == "one_early":  # one landing row in a regular node made 1 step long
            r = int(np.flatnonzero(code >= 2)[0])
            value[r] = 1
        for n, a in (("edge", edge), ("code", code), ("value", value), ("count", count)):
            _rewrite(f, f"edges/steps_{n}", a)
        if consistent:
            particles = e["particles"][()]
            total = np.bincount(edge, weights=count.astype(float) * value.astype(float), minlength=particles.size)
            terms = e["cost_terms_mean"][()]
            terms[:, 1] = total / particles
            _rewrite(f, "edges/particle_steps", total)
            _rewrite(f, "edges/steps_mean", total / particles)
            _rewrite(f, "edges/cost_terms_mean", terms)
    return fn


def _deadline_policy(kind: str) -> Callable[[h5py.File], None]:
    """The solved smoke roadmap's policy solved again with a deadline (by the file's own DP), then
    one attribute or array made to disagree."""
    def fn(f: h5py.File) -> None:
        g = f["policy"]
        if kind == "steps_attribute":
            g.attrs["deadline_steps"] = int(g.attrs["deadline_steps"]) + 5
        elif kind == "probability_attribute":
            g.attrs["deadline_success_probability"] = 1.0
        elif kind == "success_array":
            s = g["deadline_success"][()]
            s[:, 0] = 1.0
            _rewrite(f, "policy/deadline_success", s)
        elif kind == "one_array":
            del g["deadline_success"]
        elif kind == "attribute_without_arrays":
            del g["deadline_edge"], g["deadline_success"]
    return fn


def table_cases() -> list[Case]:
    swept = [("inverted", "inspect", ("'/edges/swept_hi'", "below")), ("inverted", "update", ("'/edges/swept_hi'",)),
             ("point", "update", ("'/edges/swept_lo'", "source node")), ("inf", "update", ("'/edges/swept_lo'",)),
             ("nan", "solve", ("'/edges/swept_hi'", "non-finite")), ("moved", "update", ("'/edges/swept_lo'",)),
             ("one_row_inverted", "update", ("'/edges/swept_hi'", "row 3")),
             ("third_dim", "update", ("'/edges/swept_lo'", "world has 2")),
             ("third_dim", "execute", ("'/edges/swept_lo'",)), ("huge", "update", ("'/edges/swept_lo'",))]
    cases = [table(f"swept_{kind}", _swept(kind), command, phrases) for kind, command, phrases in swept]
    steps = [("all_in_one_step", ("'/edges/steps_value'", "before its nominal")),
             ("moved_outcome", ("'/edges/steps_count'", "outcome counts")),
             ("beyond_max_steps", ("'/edges/steps_value'", "controller.max_steps")),
             ("just_beyond", ("'/edges/steps_value'",)), ("one_early", ("'/edges/steps_value'", "before")),
             ("goal_in_one_step", ("'/edges/steps_value'", "particle_steps"))]
    cases += [table(f"steps_{kind}", _steps(kind, kind != "goal_in_one_step"), "solve", phrases, ("--deadline", "40"))
              for kind, phrases in steps]
    cases += [table("steps_all_in_one_step_sums_kept", _steps("all_in_one_step", False), "solve",
                    ("'/edges/steps_value'", "particle_steps"), ("--deadline", "40"))]
    cases += [table("steps_moved_outcome", _steps("moved_outcome"), "execute", ("'/edges/steps_count'",))]
    return cases


def deadline_table_cases() -> list[Case]:
    """The time-indexed policy's attributes against its arrays (a roadmap solved with a deadline)."""
    def case(kind: str, phrases: tuple[str, ...]) -> Case:
        def make(folder: Path, roadmap: Path) -> list[str]:
            from firmtool.io.roadmap_file import RoadmapFile
            from firmtool.pipeline.solve import solve_policy, write_policy
            write_policy(roadmap, solve_policy(RoadmapFile(roadmap), deadline=60))
            edit(roadmap, _deadline_policy(kind))
            return ["execute", str(roadmap), "-n", "2"]
        return Case(f"table_deadline_{kind}_execute", "table", make, phrases)
    return [case("steps_attribute", ("attribute 'deadline_steps' of '/policy'",)),
            case("probability_attribute", ("attribute 'deadline_success_probability' of '/policy'",)),
            case("success_array", ("'/policy/deadline_success'",)),
            case("one_array", ("'/policy/deadline_success'", "missing")),
            case("attribute_without_arrays", ("'/policy/deadline_edge'", "missing"))]


# -- side files (issue 52) ----------------------------------------------------------------------------------

def _task(kind: str, folder: Path) -> Path:
    path = folder / "task.toml"
    if kind == "fifo":
        os.mkfifo(path)
    elif kind in ("dev_zero", "dev_urandom"):
        path.symlink_to("/dev/zero" if kind == "dev_zero" else "/dev/urandom")
    elif kind == "folder":
        path.mkdir()
    elif kind == "huge":
        with open(path, "wb") as fh:  # sparse: 200 MiB declared, nothing stored
            fh.truncate(200 * 2**20)
    elif kind == "nested":
        path.write_text("[task]\ngoal = " + "[" * 3000 + "3.5, 2.5" + "]" * 3000 + "\n")
    elif kind == "nested_tables":
        path.write_text("[task]\ngoal = " + "{ a = " * 3000 + "1" + " }" * 3000 + "\n")
    elif kind == "long_array":
        path.write_text("[task]\ngoal = [" + ", ".join(["1.0"] * 5000) + "]\n")
    elif kind == "binary":
        path.write_bytes(b"[task]\ngoal = [3.5, 2.5]\n\xff\xfe" + SECRET.encode())
    elif kind == "secret_key":
        path.write_text(f"[task]\n{'k' * 50_000} = 1\n")
    elif kind == "link_to_secret":
        secret = folder / "secret.txt"
        secret.write_text(f"{SECRET}\n")
        path.symlink_to(secret)
    return path


def task_case(kind: str, phrases: tuple[str, ...]) -> Case:
    def make(folder: Path, roadmap: Path) -> list[str]:
        return ["solve", str(roadmap), "--task", str(_task(kind, folder))]
    return Case(f"task_{kind}", "side", make, ("task.toml",) + phrases)


def _store_query(f: h5py.File, name: str, image: bytes, base_edges: str) -> None:
    g = f.require_group("queries")
    d = g.create_dataset(name, data=np.frombuffer(image, dtype=np.uint8))
    d.attrs["base_edges_sha256"] = base_edges


def query_bombs(command: str, query: str, phrases: tuple[str, ...] = (), code: int = 2) -> Case:
    """A roadmap with a stored query 'own' (its own image: a valid query) and five queries declared
    0.99 GiB each but never written (a file of kilobytes): only the query asked for may be read."""
    def make(folder: Path, roadmap: Path) -> list[str]:
        image = roadmap.read_bytes()
        with h5py.File(roadmap, "r") as f:
            edges = str(f["edges"].attrs["inputs_sha256"])

        def fn(f: h5py.File) -> None:
            _store_query(f, "own", image, edges)
            for i in range(5):
                f["queries"].create_dataset(f"bomb{i}", shape=(int(0.99 * 2**30),), dtype="u1", chunks=(2**20,),
                                            compression="gzip", fillvalue=0)
        edit(roadmap, fn)
        if command == "inspect":
            return ["inspect", str(roadmap)]
        if command == "plot":
            return ["plot", str(roadmap), "--query", query, "-o", str(folder / "q.png")]
        return ["execute", str(roadmap), "--query", query, "-n", "2"]
    outputs = (".r.h5.lock", "q.png", ".q.png.lock")
    return Case(f"query_bombs_{command}_{query}", "side", make, phrases, code=code, outputs=outputs)


def side_cases() -> list[Case]:
    cases = [task_case("fifo", ("--task", "FIFO")), task_case("dev_zero", ("--task", "character device")),
             task_case("dev_urandom", ("--task", "character device")), task_case("folder", ("--task", "directory")),
             task_case("huge", ("--task", "at most")), task_case("nested", ("task.goal", "nested at most")),
             task_case("nested_tables", ("task.goal", "nested at most")),
             task_case("long_array", ("task.goal", "at most 1000 items")), task_case("binary", ("--task", "UTF-8")),
             task_case("secret_key", ("task.kkkk", "(50000 characters)")), task_case("link_to_secret", ("--task",))]
    cases += [query_bombs("execute", "own", code=0), query_bombs("plot", "own", code=0),
              query_bombs("inspect", "", code=0),
              query_bombs("execute", "bomb3", ("'/queries/bomb3'", "declares")),
              query_bombs("plot", "bomb0", ("'/queries/bomb0'", "declares"))]
    return cases


# -- deadline budgets and messages (issue 52) ---------------------------------------------------------------

def deadline_cases() -> list[Case]:
    def solve(value: str) -> Case:
        return Case(f"deadline_{value}", "deadline",
                    lambda folder, roadmap: ["solve", str(roadmap), "--deadline", value],
                    ("--deadline", "expected a deadline of at most", "longest simple chain"))
    cases = [solve(v) for v in ("10000000", "1000000000000", str(2**63), str(10**40))]
    cases += [scenario_case(f"deadline_steps_{v}_check", "deadline",
                            scenario_text(**{"[task]\n": f"[task]\ndeadline_steps = {v}\n"}), "check",
                            ("task.deadline_steps", "at most")) for v in ("1000000000000", "2000000")]
    cases += [scenario_case("deadline_steps_2_63_check", "deadline",
                            scenario_text(**{"[task]\n": f"[task]\ndeadline_steps = {2**63}\n"}), "check",
                            ("task.deadline_steps",))]
    return cases


def _no_edge_world(folder: Path) -> Path:
    """The smoke world with walls that put every node but the start and goal in collision and cut
    every nominal between them."""
    path = folder / "walled.toml"
    path.write_text(scenario_text(**{
        "obstacles = [ { center = [2.0, 1.2], half_size = [0.3, 0.7] } ]":
            "obstacles = [ { center = [2.0, 1.5], half_size = [1.2, 1.5] }, { center = [0.5, 2.0], half_size = "
            "[0.5, 1.2] }, { center = [3.6, 2.0], half_size = [0.4, 1.1] } ]"}))
    return path


def message_cases() -> list[Case]:
    long_name = "n" * 100_000
    return [
        Case("name_100kb", "message", lambda folder, roadmap: ["solve", str(roadmap), "--goal", "3.5,2.5", "--name",
                                                                long_name], ("--name", "(100000 characters)")),
        Case("name_dot", "message", lambda folder, roadmap: ["solve", str(roadmap), "--goal", "3.5,2.5", "--name", "."],
             ("--name", "found '.'")),
        Case("name_dotdot", "message", lambda folder, roadmap: ["solve", str(roadmap), "--goal", "3.5,2.5", "--name",
                                                                 ".."], ("--name",)),
        Case("name_dash", "message", lambda folder, roadmap: ["solve", str(roadmap), "--goal", "3.5,2.5", "--name",
                                                               "-x"], ("--name",)),
        Case("query_long_execute", "message", lambda folder, roadmap: ["execute", str(roadmap), "--query", long_name],
             ("--query", "(100000 characters)")),
        Case("disturbance_long", "message", lambda folder, roadmap: ["execute", str(roadmap), "-n", "1", "-d",
                                                                     "push:" + "9" * 100_000],
             ("--disturbance", "characters)")),
        Case("update_leaves_no_edge", "message",
             lambda folder, roadmap: ["update", str(roadmap), str(_no_edge_world(folder))],
             ("has no edge", "world update"), code=1, outputs=(".r.h5.lock", "r.h5")),
        Case("update_changes_a_task_field", "message",
             lambda folder, roadmap: ["update", str(roadmap), str(_changed(folder, "start = [0.5, 0.5]",
                                                                           "start = [0.5, 0.6]"))],
             ("task.start", "differs")),
        Case("update_changes_a_model_field", "message",
             lambda folder, roadmap: ["update", str(roadmap), str(_changed(folder, "dt = 0.1", "dt = 0.11"))],
             ("model.dt", "differs")),
    ]


def _changed(folder: Path, old: str, new: str) -> Path:
    path = folder / "changed.toml"
    path.write_text(scenario_text(**{old: new}))
    return path


def cli_cases() -> list[Case]:
    """Every case run through the command line in a child process."""
    cases = hdf5_cases() + lock_cases() + mesh_cases() + budget_cases() + attribute_cases() + option_cases()
    cases += table_cases() + deadline_table_cases() + side_cases() + deadline_cases() + message_cases()
    names = [c.name for c in cases]
    assert len(set(names)) == len(names), sorted(n for n in names if names.count(n) > 1)
    return cases


def prepare(folder: Path, solved: Path) -> Path:
    """``folder`` with a copy of the solved smoke roadmap as ``r.h5``; returns its path."""
    folder.mkdir(parents=True, exist_ok=True)
    roadmap = folder / "r.h5"
    shutil.copyfile(solved, roadmap)
    return roadmap
