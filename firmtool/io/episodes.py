"""Episode records in HDF5 (``firmtool execute --save-episodes FILE.h5``), for plots and audits.

Layout (``format = "firmtool-episodes"``, ``format_version = 1`` as root attributes, with the
roadmap path, seed, policy, disturbances and replanning settings)::

    /episodes/000000/            attrs: outcome, steps, cost, replans, replan_failures, disturbances
        states       (T+1, n)    true states, row 0 the start
        estimates    (T+1, n)    filter estimates
        controls     (T, m)      applied controls
        covariance_trace (T+1,)  tr P_k
        covariances  (T+1, n, n) filter covariances, only if n <= FULL_COVARIANCE_MAX_DIM;
        covariance_diag (T+1, n) otherwise (the arm's 16x16 per step would dominate the file; the
                                 full P of a policy edge is recomputed by design.local_controller)
        nodes        (K,)        node sequence (start node, or -1 when the start lay in no node)
        edges        (K',)       policy edges taken
        events       (E,)        compound: step (int64), kind (S24), node (int64), value (float64),
                                 detail (S96)

Built in memory, then written to a temporary file in the same folder and renamed
(:func:`firmtool.io.atomic.write_bytes`): a reader never sees half a file, and a full disk is one
clean error that leaves the previous file intact. An existing file at the path is replaced only if
it is a firmtool episodes file (or with ``force``).
"""

from __future__ import annotations

import io
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from firmtool.errors import InputError
from firmtool.io.atomic import check_target, write_bytes

FORMAT, FORMAT_VERSION = "firmtool-episodes", 1
FULL_COVARIANCE_MAX_DIM = 8
EVENT_DTYPE = np.dtype([("step", np.int64), ("kind", "S24"), ("node", np.int64), ("value", np.float64),
                        ("detail", "S96")])


def _events_array(events: list) -> np.ndarray:
    out = np.zeros(len(events), dtype=EVENT_DTYPE)
    for i, ev in enumerate(events):
        out[i] = (ev.step, str(ev.kind).encode()[:24], ev.node, ev.value, ev.detail.encode()[:96])
    return out


def is_episodes_file(path: str | Path) -> bool:
    """Whether ``path`` is an HDF5 file written by :func:`save_episodes`."""
    try:
        with h5py.File(path, "r") as f:
            return f.attrs.get("format") == FORMAT
    except (OSError, ValueError, KeyError, TypeError):
        return False


def check_output(path: str | Path, force: bool = False) -> Path:
    """Refuse an episodes output path that is not a firmtool episodes file (unless ``force``), a
    folder, a device, or lies under a file (:func:`firmtool.io.atomic.check_target`)."""
    return check_target(path, "episodes file", is_episodes_file, force)


def save_episodes(path: str | Path, episodes: list, attrs: dict[str, Any], force: bool = False) -> None:
    """Write recorded episodes (:class:`firmtool.results.Episode`, from ``firmtool.simulate(...,
    record=True)``) atomically to ``path``; an existing file there is replaced only if it is a
    firmtool episodes file, or with ``force``."""
    check_output(path, force)
    image = io.BytesIO()
    with h5py.File(image, "w") as f:
        f.attrs["format"], f.attrs["format_version"] = FORMAT, FORMAT_VERSION
        for k, v in attrs.items():
            f.attrs[k] = "" if v is None else v
        group = f.create_group("episodes")
        for i, ep in enumerate(episodes):
            if ep.states is None:
                raise ValueError("episode was not recorded (run_episode(record=True))")
            g = group.create_group(f"{i:06d}")
            for k in ("outcome", "steps", "cost", "replans", "replan_failures", "disturbances"):
                v = getattr(ep, k)
                g.attrs[k] = str(v) if isinstance(v, str) else v  # an Outcome enum as its plain text
            opts = {"compression": "gzip", "shuffle": True}
            g.create_dataset("states", data=ep.states, **opts)
            g.create_dataset("estimates", data=ep.estimates, **opts)
            g.create_dataset("controls", data=ep.controls, **opts)
            g.create_dataset("covariance_trace", data=np.trace(ep.covariances, axis1=1, axis2=2), **opts)
            if ep.states.shape[1] <= FULL_COVARIANCE_MAX_DIM:
                g.create_dataset("covariances", data=ep.covariances, **opts)
            else:
                g.create_dataset("covariance_diag", data=np.diagonal(ep.covariances, axis1=1, axis2=2), **opts)
            g.create_dataset("nodes", data=np.asarray(ep.nodes, dtype=np.int64))
            g.create_dataset("edges", data=np.asarray(ep.edges, dtype=np.int64))
            g.create_dataset("events", data=_events_array(ep.events))
    write_bytes(path, image.getbuffer())


def load_episodes(path: str | Path) -> tuple[dict[str, Any], list[dict[str, Any]]]:
    """Read a file written by :func:`save_episodes`: (root attributes, one dict per episode).

    Events come back as a list of dicts with str ``kind`` and ``detail``.
    """
    try:
        f = h5py.File(path, "r")
    except OSError as exc:
        raise InputError(f"{path}: not a readable episodes file ({exc})") from None
    with f:
        if f.attrs.get("format") != FORMAT:
            raise InputError(f"{path}: not a firmtool episodes file")
        if int(f.attrs.get("format_version", -1)) != FORMAT_VERSION:
            raise InputError(f"{path}: episodes format version {f.attrs.get('format_version')} is not "
                             f"{FORMAT_VERSION}; re-run 'firmtool execute --save-episodes'")
        attrs = {k: (v.item() if isinstance(v, np.generic) else v) for k, v in f.attrs.items()}
        out = []
        for name in sorted(f["episodes"]):
            g = f["episodes"][name]
            ep: dict[str, Any] = {k: (v.item() if isinstance(v, np.generic) else v) for k, v in g.attrs.items()}
            for k in g:
                ep[k] = g[k][()]
            ep["events"] = [{"step": int(e["step"]), "kind": e["kind"].decode(), "node": int(e["node"]),
                             "value": float(e["value"]), "detail": e["detail"].decode()} for e in ep["events"]]
            out.append(ep)
    return attrs, out
