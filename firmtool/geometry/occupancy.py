"""Occupancy-grid maps (:class:`Map`): the grid, its Euclidean distance field and the collision test
of discs and capsules against it, written once in numpy here and once compiled in the Monte Carlo
engine (:mod:`firmtool.estimation.compiled.maps`), with the same arithmetic in the same order so that
both engines give the same verdict, particle by particle.

Orientation
-----------
``Map.occupied[i, j]`` (rows, cols) is the cell in row ``i`` counted from the map's BOTTOM (smallest y
in the map's frame) and column ``j`` from its left: the layout of ``nav_msgs/OccupancyGrid`` (row-major
from the origin), and the image of a map_server map flipped upside down (an image's first row is the
map's top). Cell ``(i, j)`` covers ``[j, j + 1) * resolution`` in x and ``[i, i + 1) * resolution`` in y
of the map's frame, whose origin is the world pose ``origin = (x, y, yaw)`` (the lower-left corner of
cell (0, 0); the frame is turned by ``yaw`` about it, counter-clockwise). Everything outside the grid
counts as occupied.

Collision: the conservative rule
--------------------------------
An occupied cell is its whole square. With ``D(c)`` the Euclidean distance from cell ``c``'s centre
to the nearest occupied cell's centre (scipy's exact ``distance_transform_edt``, on the grid padded by
one ring of occupied cells, so that the outside counts), and ``h = resolution / sqrt(2)`` half a cell's
diagonal, a disc of radius ``r`` centred at ``p`` in cell ``c`` is declared FREE iff

    ``F(c) > 0  and  |p - centre(c)|^2 < F(c)^2``,  where ``F(c) = D(c) - h - r``

(the clearance field, computed once per radius). This never declares free a disc that meets an
occupied square: every point of an occupied square ``o`` is within ``h`` of its centre, and
``|p - centre(o)| >= D(c) - |p - centre(c)|``, so the disc's distance to ``o`` is at least
``D(c) - |p - centre(c)| - h > r``. It may declare a free disc in collision within about a cell and a
half of a wall (``h + |p - centre(c)| <= 2 h``): the price of a test that reads one cell.

A capsule (segment ``a``-``b`` of radius ``r``) is tested as ``n = ceil(|b - a| / resolution) + 1``
discs evenly spaced along the segment (spacing ``s <= resolution``), each of radius ``r + s / 2``
(every point of the capsule is within ``r + s / 2`` of one of them), i.e. ``F(c) - s/2`` in place of
``F(c)``. A zero-length segment is one disc of radius ``r``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from firmtool.errors import InputError
from firmtool.io.map_file import MAX_CELLS_SIDE, OCCUPIED, UNKNOWN, classify_percent, read_map_yaml

UNKNOWN_CHOICES = ("occupied", "free")
# the most discs - 1 along one capsule (a segment of a million cells is no robot on a map)
MAX_SEGMENT_STEPS = 1e6


def _origin(origin) -> tuple[float, float, float]:
    try:
        o = tuple(float(v) for v in origin)
    except (TypeError, ValueError):
        raise InputError(f"map origin: expected (x, y, yaw) numbers, found {origin!r:.80}") from None
    if len(o) == 2:
        o = (o[0], o[1], 0.0)
    if len(o) != 3 or not all(math.isfinite(v) for v in o):
        raise InputError(f"map origin: expected three finite numbers (x, y, yaw), found {o}")
    return o


@dataclass(init=False, eq=False, repr=False)
class Map:
    """An occupancy-grid map (module notes: orientation and the collision rule).

    Parameters
    ----------
    occupied : (rows, cols) bool (or 0/1) array: True where a cell is occupied (unknown cells already
        decided), row 0 the map's bottom.
    resolution : metres (world units) per cell, > 0.
    origin : ``(x, y, yaw)`` (or ``(x, y)``) of the lower-left corner of cell (0, 0).
    unknown : optional (rows, cols) bool: which cells were unknown in the source (kept for figures; the
        collision test reads only ``occupied``).

    Examples
    --------
    >>> import numpy as np, firmtool as ft
    >>> grid = np.zeros((40, 60), dtype=bool); grid[:, 30] = True      # a wall at x = 3.0 .. 3.1
    >>> m = ft.Map(grid, 0.1, (0.0, 0.0, 0.0))
    >>> m.bounds
    (array([0., 0.]), array([6., 4.]))
    >>> m.world_to_cell(np.array([[3.05, 1.0]]))
    (array([10]), array([30]))
    """

    # its identity (the edge keys' digest, firmtool.io.hashing): the grid, resolution and origin
    occupied: np.ndarray
    resolution: float
    origin: tuple[float, float, float]

    def __init__(self, occupied: np.ndarray, resolution: float, origin=(0.0, 0.0, 0.0), *,
                 unknown: np.ndarray | None = None) -> None:
        grid = np.asarray(occupied)
        if grid.ndim != 2 or grid.shape[0] < 1 or grid.shape[1] < 1:
            raise InputError(f"map: expected a (rows, cols) occupancy array, found shape {grid.shape}")
        if grid.shape[0] > MAX_CELLS_SIDE or grid.shape[1] > MAX_CELLS_SIDE:
            raise InputError(f"map: expected at most {MAX_CELLS_SIDE} x {MAX_CELLS_SIDE} cells, found {grid.shape}")
        if grid.dtype != np.bool_:
            if not np.issubdtype(grid.dtype, np.number) or not np.all(np.isin(grid, (0, 1))):
                raise InputError("map: expected a bool (or 0/1) occupancy array")
            grid = grid.astype(bool)
        try:
            res = float(resolution)
        except (TypeError, ValueError):
            raise InputError(f"map resolution: expected a positive number, found {resolution!r:.80}") from None
        if not (math.isfinite(res) and res > 0):
            raise InputError(f"map resolution: expected a positive number, found {res}")
        self.occupied = np.ascontiguousarray(grid)
        self.occupied.flags.writeable = False
        self.resolution = res
        self.origin = _origin(origin)
        self.unknown = None if unknown is None else np.ascontiguousarray(np.asarray(unknown, dtype=bool))
        if self.unknown is not None and self.unknown.shape != grid.shape:
            raise InputError(f"map unknown: expected shape {grid.shape}, found {self.unknown.shape}")
        self.source: str | None = None  # the file it was read from, if any (for messages)
        self._distance: np.ndarray | None = None
        self._clearance: dict[float, np.ndarray] = {}

    # --- constructors ---------------------------------------------------------------------------

    @classmethod
    def from_cells(cls, cells: np.ndarray, resolution: float, origin, unknown: str = "occupied") -> "Map":
        """A map from trinary cells (rows, cols) of 0 free, 100 occupied, -1 unknown (row 0 the bottom);
        ``unknown``: ``"occupied"`` (the default) or ``"free"``, what an unknown cell counts as."""
        if unknown not in UNKNOWN_CHOICES:
            raise InputError(f"map unknown: expected one of {', '.join(UNKNOWN_CHOICES)}, found {unknown!r:.40}")
        cells = np.asarray(cells)
        unk = cells == UNKNOWN
        occupied = (cells == OCCUPIED) | (unk if unknown == "occupied" else False)
        return cls(occupied, resolution, origin, unknown=unk)

    @classmethod
    def from_yaml(cls, path: str | Path, unknown: str = "occupied") -> "Map":
        """A ROS map_server map: its YAML file and the image it names (:mod:`firmtool.io.map_file`:
        keys, modes, thresholds, the files it refuses).

        Raises
        ------
        firmtool.io.map_file.MapFileError
            One line naming the file and the field (an InputError).
        """
        f = read_map_yaml(path)
        m = cls.from_cells(f.cells, f.resolution, f.origin, unknown=unknown)
        m.source = str(path)
        return m

    @classmethod
    def from_occupancy_grid(cls, data, width: int, height: int, resolution: float, origin,
                            unknown: str = "occupied", occupied_thresh: float = 0.65,
                            free_thresh: float = 0.196) -> "Map":
        """A map from a ``nav_msgs/OccupancyGrid``'s fields: ``data`` (``width * height`` values,
        row-major from the origin, -1 unknown, 0..100 occupancy percent), ``info.width``,
        ``info.height``, ``info.resolution`` and the origin's ``(x, y, yaw)``. A cell is occupied where
        its value exceeds ``occupied_thresh * 100``, free below ``free_thresh * 100``, unknown otherwise
        (as a map_server map's thresholds).

        Raises
        ------
        InputError
            ``data`` of another size than ``width * height``, or values outside -1..100.
        """
        try:
            w, h = int(width), int(height)
        except (TypeError, ValueError):
            raise InputError(f"occupancy grid: expected integer width and height, found {width!r:.40}, "
                             f"{height!r:.40}") from None
        if w < 1 or h < 1 or w > MAX_CELLS_SIDE or h > MAX_CELLS_SIDE:
            raise InputError(f"occupancy grid: expected 1..{MAX_CELLS_SIDE} cells a side, found {w} x {h}")
        values = np.asarray(data)
        if values.ndim != 1 or values.size != w * h:
            raise InputError(f"occupancy grid: expected width * height = {w * h} values, found {values.size}")
        if values.size and (not np.issubdtype(values.dtype, np.integer) or values.min() < -1 or values.max() > 100):
            raise InputError("occupancy grid: expected integer values in -1..100")
        cells = classify_percent(values.reshape(h, w), occupied_thresh, free_thresh)
        return cls.from_cells(cells, resolution, origin, unknown=unknown)

    # --- geometry -------------------------------------------------------------------------------

    @property
    def shape(self) -> tuple[int, int]:
        return self.occupied.shape

    @property
    def yaw(self) -> float:
        return self.origin[2]

    def corners(self) -> np.ndarray:
        """(4, 2) world corners of the grid (lower-left, lower-right, upper-right, upper-left)."""
        rows, cols = self.shape
        local = np.array([[0.0, 0.0], [cols, 0.0], [cols, rows], [0.0, rows]]) * self.resolution
        c, s = math.cos(self.yaw), math.sin(self.yaw)
        return np.stack([self.origin[0] + c * local[:, 0] - s * local[:, 1],
                         self.origin[1] + s * local[:, 0] + c * local[:, 1]], axis=1)

    @property
    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """``(lo, hi)`` (2,): the axis-aligned box around the grid (its extent, a turned map's box)."""
        k = self.corners()
        return k.min(axis=0), k.max(axis=0)

    def _frame(self) -> tuple[float, float, float, float]:
        """(ox, oy, cos yaw, sin yaw) as both engines use them (yaw 0: exactly 1 and 0)."""
        yaw = self.yaw
        return self.origin[0], self.origin[1], (math.cos(yaw) if yaw else 1.0), (math.sin(yaw) if yaw else 0.0)

    def to_local(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """World points (..., 2) -> their coordinates in the map's frame ``(lx, ly)``."""
        P = np.asarray(points, dtype=float)
        ox, oy, c, s = self._frame()
        dx, dy = P[..., 0] - ox, P[..., 1] - oy
        return dx * c + dy * s, dy * c - dx * s

    def world_to_cell(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """World points (..., 2) -> ``(row, col)`` integer arrays (...,); a point outside the grid gets
        an index outside ``[0, rows) x [0, cols)`` (NaN: -1)."""
        lx, ly = self.to_local(points)
        fi, fj = np.floor(ly * self.inverse), np.floor(lx * self.inverse)
        big = 2.0 * MAX_CELLS_SIDE
        fi = np.where(np.isnan(fi), -1.0, np.clip(fi, -big, big))
        fj = np.where(np.isnan(fj), -1.0, np.clip(fj, -big, big))
        return fi.astype(np.int64), fj.astype(np.int64)

    def cell_centers(self, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
        """World centres (..., 2) of cells ``(rows, cols)``."""
        lx = (np.asarray(cols) + 0.5) * self.resolution
        ly = (np.asarray(rows) + 0.5) * self.resolution
        ox, oy, c, s = self._frame()
        return np.stack([ox + c * lx - s * ly, oy + s * lx + c * ly], axis=-1)

    # --- distance field and the collision test ----------------------------------------------------

    def distance_field(self) -> np.ndarray:
        """(rows, cols) float: the Euclidean distance (world units) from each cell's centre to the
        nearest occupied cell's centre, the outside of the grid counting as occupied (0 in occupied
        cells). scipy's exact Euclidean distance transform, computed once."""
        if self._distance is None:
            # scipy.ndimage: ~0.9 s to import here, so only where a map is used (scenario reading imports this module)
            import scipy.ndimage

            padded = np.pad(~self.occupied, 1, constant_values=False)  # the ring outside: occupied
            d = scipy.ndimage.distance_transform_edt(padded, sampling=self.resolution)[1:-1, 1:-1]
            self._distance = np.ascontiguousarray(d, dtype=np.float64)
            self._distance.flags.writeable = False
        return self._distance

    def clearance(self, radius: float) -> np.ndarray:
        """(rows, cols) float ``F = D - resolution / sqrt(2) - radius`` (module notes): a disc of
        ``radius`` centred in a cell is free iff ``F > 0`` and its centre is nearer than ``F`` to the
        cell's centre. Computed once per radius."""
        r = float(radius)
        hit = self._clearance.get(r)
        if hit is None:
            hit = self.distance_field() - self.resolution / math.sqrt(2.0) - r
            hit.flags.writeable = False
            if len(self._clearance) > 8:
                self._clearance.clear()
            self._clearance[r] = hit
        return hit

    def geometry(self) -> np.ndarray:
        """(8,) float: ``ox, oy, cos yaw, sin yaw, resolution, rows, cols, 1 / resolution``: the compiled
        test's frame."""
        ox, oy, c, s = self._frame()
        rows, cols = self.shape
        return np.array([ox, oy, c, s, self.resolution, rows, cols, self.inverse], dtype=np.float64)

    @property
    def inverse(self) -> float:
        """``1 / resolution``: both engines multiply by it (a division costs several multiplications)."""
        return 1.0 / self.resolution

    def discs_hit(self, points: np.ndarray, radius: float, extra: np.ndarray | float = 0.0) -> np.ndarray:
        """bool (...,): the discs of ``radius + extra`` centred at ``points`` (..., 2) are not free by the
        module's rule (outside the grid, NaN, or too near an occupied cell). The numpy twin of
        :func:`firmtool.estimation.compiled.maps.disc_hits`."""
        F = self.clearance(radius)
        ox, oy, c, s = self._frame()
        res = self.resolution
        rows, cols = self.shape
        P = np.asarray(points, dtype=float)
        dx, dy = P[..., 0] - ox, P[..., 1] - oy
        lx, ly = dx * c + dy * s, dy * c - dx * s
        fi, fj = np.floor(ly * self.inverse), np.floor(lx * self.inverse)
        inside = (fi >= 0) & (fi < rows) & (fj >= 0) & (fj < cols)  # False for NaN
        i = np.where(inside, fi, 0).astype(np.int64)
        j = np.where(inside, fj, 0).astype(np.int64)
        f = F[i, j] - extra
        ex, ey = lx - (j + 0.5) * res, ly - (i + 0.5) * res
        free = inside & (f > 0) & (ex * ex + ey * ey < f * f)
        return ~free

    def capsules_hit(self, starts: np.ndarray, ends: np.ndarray, radius: float) -> np.ndarray:
        """bool (M,): some capsule ``[starts, ends]`` (M, L, 2) of ``radius`` is not free by the module's
        rule (discs along each segment, at most a cell apart). The numpy twin of the compiled
        :func:`firmtool.estimation.compiled.maps.capsule_hits`."""
        S = np.asarray(starts, dtype=float)
        E = np.asarray(ends, dtype=float)
        M = S.shape[0]
        if M == 0 or S.shape[1] == 0:
            return np.zeros(M, dtype=bool)
        if starts is ends or np.array_equal(S, E):  # discs (a robot of balls): the general path's t = 0, extra 0
            return self.discs_hit(S, radius).any(axis=1)
        vx, vy = E[..., 0] - S[..., 0], E[..., 1] - S[..., 1]
        length = np.sqrt(vx * vx + vy * vy)
        steps = np.ceil(length * self.inverse)  # discs - 1 along each segment (NaN: the disc at S refuses it)
        steps = np.where(np.isfinite(steps), np.minimum(steps, MAX_SEGMENT_STEPS), 0.0)
        some = steps > 0
        div = np.where(some, steps, 1.0)
        half = np.where(some, 0.5 * length / div, 0.0)  # half the spacing: each disc's extra radius
        hit = np.zeros(M, dtype=bool)
        for k in range(int(steps.max()) + 1):  # a loop over positions along the segments, not particles
            on = k <= steps
            t = np.where(some, k / div, 0.0)
            pts = np.stack([S[..., 0] + t * vx, S[..., 1] + t * vy], axis=-1)
            hit |= (self.discs_hit(pts, radius, half) & on).any(axis=1)
        return hit

    # --- drawing --------------------------------------------------------------------------------

    def draw(self, ax, *, color=(0.25, 0.25, 0.3), zorder: float = 1.5, label: str | None = "map"):
        """Draw the map into matplotlib axes ``ax``: occupied cells in ``color``, unknown ones (when the
        source had any) in a lighter shade, free cells transparent; turned by the origin's yaw.
        Returns the image artist."""
        import matplotlib.transforms as mtransforms  # matplotlib only where a figure is drawn

        rows, cols = self.shape
        rgba = np.zeros((rows, cols, 4))
        rgba[..., :3] = color
        rgba[..., 3] = np.where(self.occupied, 1.0, 0.0)
        if self.unknown is not None:
            rgba[self.unknown, 3] = 0.35
        ox, oy, _, _ = self._frame()
        res = self.resolution
        image = ax.imshow(rgba, origin="lower", extent=(ox, ox + cols * res, oy, oy + rows * res),
                          interpolation="nearest", zorder=zorder, label=label)
        if self.yaw:
            image.set_transform(mtransforms.Affine2D().rotate_around(ox, oy, self.yaw) + ax.transData)
        return image

    # --- changes --------------------------------------------------------------------------------

    def same_frame(self, other: "Map") -> bool:
        """Same shape, resolution and origin (cells compare one to one)."""
        return self.shape == other.shape and self.resolution == other.resolution and self.origin == other.origin

    def changed_boxes(self, other: "Map", margin: float | None = None) -> tuple[np.ndarray, np.ndarray]:
        """World boxes ``(lo, hi)`` (K, 2) around the cells whose occupancy differs between ``self`` and
        ``other`` (one box per connected group of changed cells), grown by ``margin`` beyond the robot's
        radius (default three cells). Why three: a disc at ``p`` in cell ``c`` reads whether some occupied
        centre lies within ``r + h + e + |p - centre(c)|`` of ``centre(c)`` (``h`` half a cell's diagonal,
        ``e <= resolution / 2`` a capsule disc's extra radius), so a changed cell can alter its verdict only
        if the cell's square is within ``r + 3 h + resolution / 2 < r + 2.62 * resolution`` of ``p``; the
        caller grows the swept regions by ``r`` (:func:`firmtool.roadmap.world_change.meets`). Maps in
        another frame: one infinite box."""
        if not self.same_frame(other):
            return np.full((1, 2), -np.inf), np.full((1, 2), np.inf)
        import scipy.ndimage  # lazily, as in distance_field

        grow = 3.0 * self.resolution if margin is None else float(margin)
        changed = self.occupied != other.occupied
        labels, n = scipy.ndimage.label(changed, structure=np.ones((3, 3), dtype=int))
        lo, hi = [], []
        for sl in scipy.ndimage.find_objects(labels)[:n]:
            r0, r1, c0, c1 = sl[0].start, sl[0].stop, sl[1].start, sl[1].stop
            res = self.resolution
            local = np.array([[c0, r0], [c1, r0], [c1, r1], [c0, r1]], dtype=float) * res
            ox, oy, c, s = self._frame()
            wx = ox + c * local[:, 0] - s * local[:, 1]
            wy = oy + s * local[:, 0] + c * local[:, 1]
            lo.append([wx.min() - grow, wy.min() - grow])
            hi.append([wx.max() + grow, wy.max() + grow])
        return np.array(lo, dtype=float).reshape(-1, 2), np.array(hi, dtype=float).reshape(-1, 2)

    # --- values ---------------------------------------------------------------------------------

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Map):
            return NotImplemented
        return self.same_frame(other) and bool(np.array_equal(self.occupied, other.occupied))

    __hash__ = None  # type: ignore[assignment]

    def __repr__(self) -> str:
        rows, cols = self.shape
        return (f"Map({rows} x {cols} cells of {self.resolution:g}, origin={self.origin}, "
                f"{int(self.occupied.sum())} occupied)")



class MapCollisionBackend:
    """A collision backend with an occupancy map on top of another's world (its bounds and obstacles):
    a capsule collides where ``inner`` says so or where the map's rule (module notes) does not declare
    it free. What :func:`firmtool.geometry.registry.backend_for_world` builds for a world with a map.

    Parameters
    ----------
    inner : the backend of the world's bounds and obstacles.
    grid : the map.
    """

    def __init__(self, inner, grid: Map) -> None:
        self.inner, self.grid = inner, grid
        self.self_collision = inner.self_collision

    def capsules_collide(self, starts: np.ndarray, ends: np.ndarray, radius: float) -> np.ndarray:
        """See :class:`firmtool.geometry.backends.CollisionBackend`: bool (M,)."""
        hit = np.asarray(self.inner.capsules_collide(starts, ends, radius))
        return hit | self.grid.capsules_hit(starts, ends, radius)

    def __getattr__(self, name: str):
        if name.startswith("__") or name in ("inner", "grid"):  # unpickling: no inner yet
            raise AttributeError(name)
        return getattr(self.inner, name)
