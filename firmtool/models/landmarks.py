"""Range-bearing landmark sensing: the measurement of a planar robot that sees known landmarks.

``[measurement] kind = "imperfect", model = "landmarks"``: each landmark ``l = (lx, ly)`` that the
robot at position ``p = (px, py)`` (heading ``theta`` for a robot that has one, else 0) sees gives
two rows of the measurement, in landmark order:

    range   r = |l - p|                        std  range_std + range_std_growth r
    bearing b = wrap(atan2(ly - py, lx - px) - theta)   std  bearing_std

``wrap`` takes an angle to ``(-pi, pi]``; so is every bearing residual (:func:`wrap_pi`). A landmark
is seen when ``0 < r <= max_range``, ``|b| <= fov / 2`` and, with ``occlusion`` and an occupancy grid
(:class:`OcclusionGrid`, the world's map), no occupied cell lies between the robot and the landmark
(:func:`occluded`: an exact grid traversal, Amanatides and Woo's, of the cells the segment
crosses, the landmark's own cell excepted; outside the grid nothing occludes). Correspondences are
known. A landmark not seen contributes no row: its two measurement entries are NaN, its innovation
is 0, and where the filter is designed (the nominal states) its Jacobian rows are 0, which gives it a
zero gain, exactly as if its rows were absent (``K = P H' S^-1`` has a zero column where ``H`` has a
zero row, whatever finite variance the row has).

The filter is the extended one: the measurement is predicted at the estimate (``h`` of the
prediction, the innovation taken there) and linearised (:meth:`LandmarkModel.observation_jacobian`,
analytic, checked against finite differences in ``tests/test_landmarks.py``); as everywhere in
firmtool (METHOD.md 3), the gains are designed once per edge, linearised along its nominal (and per
node at its centre or along its orbit), so that every particle of the Monte Carlo runs the filter the
policy runs and the covariances are deterministic.

:class:`LandmarkSensing` is the noise registry's form ``landmarks`` (it declares the keys);
:class:`LandmarkModel` is the robot's dynamics with this sensor in place of its own (built once per
problem, :func:`firmtool.problem.build_problem`). The ray march is compiled (numba) and used by both
Monte Carlo engines; the compiled engine's twin of the measurement and the update is in
:mod:`firmtool.estimation.compiled.model`.
"""

from __future__ import annotations

import csv
import io
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar, Mapping

import numpy as np

from firmtool.errors import InputError
from firmtool.io.limits import LimitError, read_regular_file
from firmtool.jit import KERNEL_OPTIONS, cached_njit, numba
from firmtool.models.noise import NoiseModel, register
from firmtool.util.schema import Field

MIN_RANGE = 1e-6  # m: a landmark closer than this has no bearing; it is not seen
MAX_LANDMARKS = 1000  # landmarks in a scenario or CSV file (two measurement rows each)
MAX_CSV_BYTES = 2**20  # a landmark CSV file of more is refused before it is read


def wrap_pi(a):
    """``a`` (any shape) modulo a turn, in ``(-pi, pi]`` (a bearing and a bearing's residual)."""
    return np.pi - np.mod(np.pi - a, 2.0 * np.pi)


def _check_fov(v: float) -> str | None:
    return None if 0.0 < v <= 360.0 else f"expected 0 < fov <= 360 (degrees), found {v!r}"


def _check_landmarks(a: np.ndarray) -> str | None:
    if a.shape[0] == 0:
        return "expected at least one landmark [x, y]"
    if a.shape[0] > MAX_LANDMARKS:
        return f"expected at most {MAX_LANDMARKS} landmarks, found {a.shape[0]}"
    return None


@dataclass(frozen=True, eq=False)
class LandmarkSensing(NoiseModel):
    """The keys and the noise of range-bearing landmark sensing (see the module docs).

    Attributes
    ----------
    landmarks : (L, 2) the landmarks' positions (from the scenario, or read from ``landmarks_file``).
    landmarks_file : a CSV file of ``x,y`` rows (a header row allowed), relative to the scenario; "" none.
    max_range : range beyond which a landmark is not seen.
    fov : field of view in degrees, centred on the heading (on +x for a robot without one).
    range_std, range_std_growth : the range's std at range r is ``range_std + range_std_growth r``.
    bearing_std : the bearing's std (rad).
    occlusion : whether occupied cells of the world's map hide landmarks.
    """

    landmarks: np.ndarray | None
    landmarks_file: str
    max_range: float
    fov: float
    range_std: float
    bearing_std: float
    range_std_growth: float
    occlusion: bool

    form: ClassVar[str] = "landmarks"
    compiled: ClassVar[str | None] = "landmarks"
    fields: ClassVar[tuple[Field, ...]] = (
        Field("landmarks", "array", None, shape=(None, 2), unit="workspace", check=_check_landmarks,
              doc="the landmarks' positions [[x, y], ...] (or landmarks_file)", example=[[1.0, 2.0], [3.0, 0.5]]),
        Field("landmarks_file", "string", "", doc="a CSV file of x,y rows (one landmark each, a header row "
                                                 "allowed), relative to the scenario file (or landmarks)",
              example="landmarks.csv"),
        Field("max_range", "number", bound="positive", unit="workspace", doc="range beyond which a landmark is not seen",
              example=3.0),
        Field("fov", "number", 360.0, unit="degrees", check=_check_fov,
              doc="field of view, centred on the heading (on +x for a robot without one), in (0, 360]"),
        Field("range_std", "number", bound="positive", unit="workspace", doc="std of a range measurement at range 0",
              example=0.05),
        Field("range_std_growth", "number", 0.0, bound="nonnegative", unit="1",
              doc="growth of the range's std with the range (std = range_std + range_std_growth r)"),
        Field("bearing_std", "number", bound="positive", unit="rad", doc="std of a bearing measurement", example=0.05),
        Field("occlusion", "boolean", True, doc="whether occupied cells of the world's map hide the landmarks "
                                                "behind them (without a map nothing does)"),
    )
    #: this form is the whole measurement (the model is wrapped, :func:`with_landmarks`), not a variance law
    measurement_model: ClassVar[bool] = True

    @classmethod
    def resolve(cls, values: dict[str, Any], path: str, errors, prefix: str) -> None:
        """Read ``landmarks_file`` (relative to the scenario ``path``) into ``values["landmarks"]``, or
        record why not; record "no landmarks" if neither key gives one."""
        given, file = values.get("landmarks"), values.get("landmarks_file", "")
        if given is not None and file:
            errors.add(f"{prefix}.landmarks_file", "expected landmarks or landmarks_file, not both")
            return
        if file:
            try:
                values["landmarks"] = read_landmarks_csv(Path(path).parent / file, f"{prefix}.landmarks_file")
            except InputError as exc:
                errors.add(f"{prefix}.landmarks_file", str(exc))
        elif given is None:
            errors.add(f"{prefix}.landmarks", "expected at least one landmark: give landmarks = [[x, y], ...] "
                                              "or landmarks_file")

    @classmethod
    def from_values(cls, values: Mapping[str, Any]) -> "LandmarkSensing":
        kw = {f.name: values[f.name] for f in cls.fields}
        kw["landmarks"] = np.ascontiguousarray(kw["landmarks"], dtype=float).reshape(-1, 2)
        kw["occlusion"] = bool(kw["occlusion"])
        return cls(**kw)

    def variance(self, sensing: np.ndarray) -> np.ndarray:
        raise InputError("landmark sensing is a measurement model, not a variance law of a sensing coordinate")

    @property
    def count(self) -> int:
        return int(self.landmarks.shape[0])

    def constants(self) -> np.ndarray:
        """(5,) ``max_range``, half the field of view (rad), ``range_std``, ``range_std_growth``, ``bearing_std``."""
        return np.array([self.max_range, 0.5 * np.deg2rad(self.fov), self.range_std, self.range_std_growth,
                         self.bearing_std])


def read_landmarks_csv(path: str | Path, field_name: str = "landmarks_file") -> np.ndarray:
    """The landmarks (L, 2) of a CSV file of ``x,y`` rows (blank lines and one header row allowed),
    read with a size cap (:data:`MAX_CSV_BYTES`). InputError naming the line of a bad row."""
    try:
        raw = read_regular_file(path, MAX_CSV_BYTES)
    except LimitError as exc:
        raise InputError(f"{path}: {exc}") from None
    except OSError as exc:
        raise InputError(f"cannot read {path}: {exc.strerror or exc}") from None
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError:
        raise InputError(f"{path}: expected a UTF-8 text file of x,y rows") from None
    rows: list[tuple[float, float]] = []
    for line_no, row in enumerate(csv.reader(io.StringIO(text)), start=1):
        cells = [c.strip() for c in row]
        if not cells or all(c == "" for c in cells) or cells[0].startswith("#"):
            continue
        try:
            if len(cells) != 2:
                raise ValueError
            x, y = float(cells[0]), float(cells[1])
        except ValueError:
            if not rows and line_no == 1 and len(cells) == 2:
                continue  # a header row
            raise InputError(f"{path}: line {line_no}: expected a row 'x,y' of two numbers, found {','.join(cells)[:80]!r}") \
                from None
        if not (math.isfinite(x) and math.isfinite(y)) or max(abs(x), abs(y)) > 1e12:
            raise InputError(f"{path}: line {line_no}: expected finite coordinates, found {x!r}, {y!r}")
        rows.append((x, y))
        if len(rows) > MAX_LANDMARKS:
            raise InputError(f"{path}: line {line_no}: expected at most {MAX_LANDMARKS} landmarks")
    if not rows:
        raise InputError(f"{path}: expected at least one landmark row 'x,y'")
    return np.array(rows, dtype=float)


# -- occlusion ---------------------------------------------------------------------------------------

@dataclass(frozen=True, eq=False)
class OcclusionGrid:
    """An occupancy grid for the ray march: ``occupied[iy, ix]`` (uint8, 1 occupied) is the cell
    ``[ix res, (ix + 1) res) x [iy res, (iy + 1) res)`` of the grid's frame (row 0 at the bottom), whose
    origin is the world pose ``(x0, y0, yaw)`` (a ROS map's origin, :class:`firmtool.geometry.occupancy.Map`)."""

    occupied: np.ndarray
    resolution: float
    origin: tuple[float, ...]

    def __post_init__(self) -> None:
        occ = np.ascontiguousarray(self.occupied, dtype=np.uint8)
        if occ.ndim != 2 or not (self.resolution > 0):
            raise InputError("occlusion grid: expected a 2-D array of cells and a resolution > 0")
        object.__setattr__(self, "occupied", occ)

    @classmethod
    def of_map(cls, grid) -> "OcclusionGrid":
        """The occupied cells of a :class:`~firmtool.geometry.occupancy.Map` (unknown ones as it decided)."""
        return cls(grid.occupied, grid.resolution, tuple(grid.origin))

    def group(self) -> tuple:
        """``(occupied, res, x0, y0, cos yaw, sin yaw)``, the compiled march's arguments (yaw 0: exactly 1, 0)."""
        yaw = float(self.origin[2]) if len(self.origin) > 2 else 0.0
        return (self.occupied, float(self.resolution), float(self.origin[0]), float(self.origin[1]),
                math.cos(yaw) if yaw else 1.0, math.sin(yaw) if yaw else 0.0)


NO_GRID = (np.zeros((0, 0), dtype=np.uint8), 1.0, 0.0, 0.0, 1.0, 0.0)  # nothing occludes


def occluded_py(px, py, lx, ly, occ, res, x0, y0, c, s):
    """Whether an occupied cell of ``occ`` lies on the segment from ``(px, py)`` to ``(lx, ly)``,
    the landmark's own cell excepted (Amanatides-Woo traversal of every cell the segment crosses;
    cells outside the grid are free). The grid's frame: origin ``(x0, y0)``, turned by the angle of
    cosine ``c`` and sine ``s``."""
    rows, cols = occ.shape[0], occ.shape[1]
    if rows == 0:
        return False
    ax, ay, bx, by = px - x0, py - y0, lx - x0, ly - y0
    fx, fy = (ax * c + ay * s) / res, (ay * c - ax * s) / res
    tx, ty = (bx * c + by * s) / res, (by * c - bx * s) / res
    ix, iy = int(math.floor(fx)), int(math.floor(fy))
    ex, ey = int(math.floor(tx)), int(math.floor(ty))
    dx, dy = tx - fx, ty - fy
    sx = 1 if dx > 0 else -1
    sy = 1 if dy > 0 else -1
    big = 1e300
    if dx != 0.0:
        t_max_x = ((ix + 1.0 if dx > 0 else ix * 1.0) - fx) / dx
        t_dx = 1.0 / abs(dx)
    else:
        t_max_x, t_dx = big, big
    if dy != 0.0:
        t_max_y = ((iy + 1.0 if dy > 0 else iy * 1.0) - fy) / dy
        t_dy = 1.0 / abs(dy)
    else:
        t_max_y, t_dy = big, big
    for _ in range(abs(ex - ix) + abs(ey - iy) + 2):
        if ix == ex and iy == ey:
            return False
        if 0 <= ix < cols and 0 <= iy < rows and occ[iy, ix] != 0:
            return True
        if t_max_x < t_max_y:
            if t_max_x > 1.0:
                return False
            ix += sx
            t_max_x += t_dx
        else:
            if t_max_y > 1.0:
                return False
            iy += sy
            t_max_y += t_dy
    return False


def visibility_py(P, TH, landmarks, consts, grid, occlusion, out):
    """``out[a, i] = 1`` where particle a at ``P[a]`` (heading ``TH[a]``) sees landmark i (range,
    field of view, occlusion; the module docs)."""
    max_range, half_fov = consts[0], consts[1]
    occ, res, x0, y0, c, s = grid
    for a in range(P.shape[0]):
        px, py, th = P[a, 0], P[a, 1], TH[a]
        for i in range(landmarks.shape[0]):
            dx, dy = landmarks[i, 0] - px, landmarks[i, 1] - py
            r = math.sqrt(dx * dx + dy * dy)
            seen = r > MIN_RANGE and r <= max_range
            if seen and half_fov < math.pi:
                b = math.atan2(dy, dx) - th
                b = math.pi - (math.pi - b) % (2.0 * math.pi)
                seen = abs(b) <= half_fov
            if seen and occlusion:
                seen = not occluded(px, py, landmarks[i, 0], landmarks[i, 1], occ, res, x0, y0, c, s)
            out[a, i] = seen


if numba is not None:
    occluded = cached_njit(**KERNEL_OPTIONS)(occluded_py)
else:  # pragma: no cover
    occluded = occluded_py


def _visibility_fn():
    """The compiled visibility (numba), else the Python loop."""
    return visibility_py if numba is None else _compiled_visibility


if numba is not None:  # the same loop compiled: it calls the compiled occlusion test (the global ``occluded``)
    _compiled_visibility = cached_njit(**KERNEL_OPTIONS)(visibility_py)


# -- the model ---------------------------------------------------------------------------------------

@dataclass(frozen=True, eq=False)
class LandmarkModel:
    """A robot's dynamics (``base``: any :class:`~firmtool.models.base.Model`) with range-bearing
    landmark sensing in place of its own sensor (the module docs).

    Attributes
    ----------
    base : the robot's model (its ``f``, Jacobians, ``F``, ``dt``).
    noise : the landmark sensing (:class:`LandmarkSensing`).
    heading : the state coordinate of the heading, or -1 (a robot without one: bearings from +x).
    grid : the occupancy grid that occludes, or None.
    """

    base: Any
    noise: LandmarkSensing
    heading: int = -1
    grid: OcclusionGrid | None = None
    consts: np.ndarray = field(init=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "consts", self.noise.constants())

    # the dynamics are the robot's
    @property
    def n(self) -> int:
        return self.base.n

    @property
    def m(self) -> int:
        return self.base.m

    @property
    def nz(self) -> int:
        return 2 * self.noise.count

    @property
    def dt(self) -> float:
        return self.base.dt

    @property
    def F(self) -> np.ndarray:
        return self.base.F

    @property
    def process_cov(self) -> np.ndarray:
        return self.base.process_cov

    def __getattr__(self, name: str) -> Any:  # a linear base's A, B (the node designs read them)
        if name.startswith("_") or name in ("base", "noise", "heading", "grid", "consts"):
            raise AttributeError(name)
        if name == "H":
            raise AttributeError("a landmark model has no constant H (observation_jacobian)")
        return getattr(self.base, name)

    def f(self, X: np.ndarray, U: np.ndarray) -> np.ndarray:
        return self.base.f(X, U)

    def dynamics_jacobians(self, x: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return self.base.dynamics_jacobians(x, u)

    def grid_group(self) -> tuple:
        return NO_GRID if self.grid is None or not self.noise.occlusion else self.grid.group()

    def _theta(self, X: np.ndarray) -> np.ndarray:
        return X[:, self.heading] if self.heading >= 0 else np.zeros(X.shape[0])

    def h(self, X: np.ndarray) -> np.ndarray:
        """Range and bearing to every landmark, seen or not: (M, n) -> (M, 2 L), rows (r_i, b_i)."""
        X = np.atleast_2d(np.asarray(X, dtype=float))
        lm = self.noise.landmarks
        dx, dy = lm[None, :, 0] - X[:, :1], lm[None, :, 1] - X[:, 1:2]
        out = np.empty((X.shape[0], self.nz))
        out[:, 0::2] = np.sqrt(dx * dx + dy * dy)
        out[:, 1::2] = wrap_pi(np.arctan2(dy, dx) - self._theta(X)[:, None])
        return out

    def visible(self, X: np.ndarray, any_heading: bool = False) -> np.ndarray:
        """(M, L) bool: which landmarks each state sees (range, field of view, occlusion; ``any_heading``:
        at some heading, the field of view turned as needed)."""
        X = np.atleast_2d(np.asarray(X, dtype=float))
        out = np.zeros((X.shape[0], self.noise.count), dtype=np.bool_)
        P = np.ascontiguousarray(X[:, :2])
        consts = self.consts.copy()
        if any_heading:
            consts[1] = np.pi
        _visibility_fn()(P, np.ascontiguousarray(self._theta(X)), self.noise.landmarks, consts,
                         self.grid_group(), self.noise.occlusion and self.grid is not None, out)
        return out

    @property
    def landmarks_needed(self) -> int:
        """Landmarks a node must see for a stationary belief: one fixes a position; with a heading, the
        pose turned about a single landmark measures the same, so two."""
        return 2 if self.heading >= 0 else 1

    def measurement_std(self, X: np.ndarray) -> np.ndarray:
        """(M, 2 L) the std of every row at the states (seen or not)."""
        X = np.atleast_2d(np.asarray(X, dtype=float))
        lm = self.noise.landmarks
        dx, dy = lm[None, :, 0] - X[:, :1], lm[None, :, 1] - X[:, 1:2]
        out = np.empty((X.shape[0], self.nz))
        out[:, 0::2] = self.noise.range_std + self.noise.range_std_growth * np.sqrt(dx * dx + dy * dy)
        out[:, 1::2] = self.noise.bearing_std
        return out

    def measurement_variance(self, states: np.ndarray) -> np.ndarray:
        """Diagonal of R (M, 2 L) at the states (every row; an unseen one is masked by its zero Jacobian
        row in a design and by its NaN measurement in a filter)."""
        return self.measurement_std(states) ** 2

    def R(self, state: np.ndarray) -> np.ndarray:
        return np.diag(self.measurement_variance(state)[0])

    def observation_jacobian(self, x: np.ndarray) -> np.ndarray:
        """``dh/dx`` (2 L, n) at one state, the rows of landmarks it does not see zero."""
        x = np.asarray(x, dtype=float).reshape(-1)
        lm = self.noise.landmarks
        dx, dy = lm[:, 0] - x[0], lm[:, 1] - x[1]
        r2 = dx * dx + dy * dy
        r = np.sqrt(r2)
        seen = self.visible(x[None])[0]
        safe_r, safe_r2 = np.where(seen, r, 1.0), np.where(seen, r2, 1.0)
        J = np.zeros((self.nz, self.n))
        J[0::2, 0], J[0::2, 1] = -dx / safe_r, -dy / safe_r
        J[1::2, 0], J[1::2, 1] = dy / safe_r2, -dx / safe_r2
        if self.heading >= 0:
            J[1::2, self.heading] = -1.0
        J[np.repeat(~seen, 2)] = 0.0
        return J

    def measure(self, X: np.ndarray, v: np.ndarray) -> np.ndarray:
        """Measurements of the TRUE states ``X`` (M, n) with standard normal noise ``v`` (M, 2 L): ranges
        and bearings (wrapped) with the std at the true state, NaN for the landmarks not seen."""
        X = np.atleast_2d(np.asarray(X, dtype=float))
        z = self.h(X) + self.measurement_std(X) * v
        z[:, 1::2] = wrap_pi(z[:, 1::2])
        z[np.repeat(~self.visible(X), 2, axis=1)] = np.nan
        return z

    def innovation(self, z: np.ndarray, pred: np.ndarray) -> np.ndarray:
        """``z - h(pred)`` (M, 2 L), bearing residuals wrapped to ``(-pi, pi]``, 0 where ``z`` is NaN
        (a landmark not seen contributes nothing)."""
        nu = np.asarray(z, dtype=float) - self.h(pred)
        nu[:, 1::2] = wrap_pi(nu[:, 1::2])
        return np.where(np.isnan(nu), 0.0, nu)


def with_landmarks(model: Any, sensing: LandmarkSensing, heading: int, grid: OcclusionGrid | None) -> LandmarkModel:
    """``model``'s dynamics with landmark sensing (``heading``: its state coordinate, -1 none)."""
    return LandmarkModel(base=model, noise=sensing, heading=int(heading), grid=grid)


register(LandmarkSensing.form, LandmarkSensing)
