"""The planning scene: an aggregate-count grid plus a target region, and its geometry fields.

A :class:`Scene` holds the occupancy grid of Section 2 (``obj``) together with the per-cell geometry
every later kernel needs (Section 3.1): which cells are target cells, the distance ``d(C, T)`` and the
unit vector ``t(C)`` toward the target boundary. Exact definitions are in ``docs/conventions.md``
("Grid and geometry"); the file formats of :meth:`Scene.save` are in ``docs/scene-format.md``.

The geometry kernel :func:`_geometry` evaluates every (cell, boundary segment) pair with array
operations, in row blocks and segment chunks so that memory stays bounded on large grids. Its serial
twin, with one shapely call per cell, is :func:`jaxplan.reference.geometry.reference_geometry`.
"""
from __future__ import annotations

import functools
import json
import math
import struct
import tokenize
import zipfile
import zlib
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import shapely
from jax import lax
from shapely.geometry import MultiPolygon, Polygon
from shapely.geometry import box as _shapely_box

from jaxplan.core.compilation import grid_jit

__all__ = ["FORMAT_VERSION", "MAX_FILE_SIDE", "Scene", "box", "circle", "stack_scenes"]

FORMAT_VERSION = 1

# A scene file's grid has at most this many rows and columns (64 MiB of float32 counts): a bound on
# what a file can make ``Scene.load`` allocate, checked before the counts are read.
MAX_FILE_SIDE = 4096

# A centre this close to the boundary (in cell sizes) is "on" it and therefore covered.
_ON_BOUNDARY_EPS = 1e-9

# Memory bounds of the geometry kernel: at most this many (cell, segment) pairs are live at once,
# and segments are consumed in chunks of at most this many (a row block always holds >= 1 row).
_PAIR_BUDGET = 1 << 20
_SEG_CHUNK = 1024

_F32_MAX = float(np.finfo(np.float32).max)


# --------------------------------------------------------------------------------------------------
# Shapes
# --------------------------------------------------------------------------------------------------

def circle(center, radius, resolution: int = 64) -> Polygon:
    """A circle as a regular polygon with ``resolution`` vertices on the circle (inscribed).

    The vertices sit at angles ``2 pi (k + 0.5) / resolution``: the half-step offset keeps vertices
    off the axis-aligned points ``center +- (radius, 0)``, which often coincide with cell centres.

    center: (x, y), world units; radius: world units, > 0; resolution: int >= 3.
    """
    cx, cy = (float(v) for v in center)
    radius = float(radius)
    if not (math.isfinite(cx) and math.isfinite(cy)):
        raise ValueError(f"circle: center must be two finite numbers, got {center!r}.")
    if not (math.isfinite(radius) and radius > 0):
        raise ValueError(f"circle: radius must be finite and > 0, got {radius!r}.")
    if int(resolution) < 3:
        raise ValueError(f"circle: resolution must be >= 3 vertices, got {resolution!r}.")
    n = int(resolution)
    ang = 2.0 * np.pi * (np.arange(n) + 0.5) / n
    return Polygon(np.stack([cx + radius * np.cos(ang), cy + radius * np.sin(ang)], axis=1))


def box(x0: float, y0: float, x1: float, y1: float) -> Polygon:
    """Axis-aligned rectangle ``[x0, x1] x [y0, y1]`` in world units (shapely's ``box``)."""
    return _shapely_box(x0, y0, x1, y1)


# --------------------------------------------------------------------------------------------------
# Geometry kernel
# --------------------------------------------------------------------------------------------------

def _polygons(target):
    return list(target.geoms) if isinstance(target, MultiPolygon) else [target]


def _segments(target) -> np.ndarray:
    """All boundary segments of ``target``: ``f32[M, 2, 2]``, ``[m, 0]`` = start, ``[m, 1]`` = end.

    Order (the tie-break order of ``t(C)``): polygon by polygon, exterior ring then interior rings,
    each ring in its stored vertex order. World units, (x, y).
    """
    parts = []
    for poly in _polygons(target):
        for ring in [poly.exterior, *poly.interiors]:
            xy = np.asarray(ring.coords, dtype=np.float64)[:, :2]  # closed ring: last == first
            parts.append(np.stack([xy[:-1], xy[1:]], axis=1))
    if not parts:
        return np.zeros((0, 2, 2), np.float32)
    return np.concatenate(parts, axis=0).astype(np.float32)


def _pair_terms(px, py, seg):
    """Closest-point offsets and ray crossings for every (cell, segment) pair.

    px: f32[1, W, 1], py: f32[R, 1, 1] local cell centres; seg: f32[Mc, 2, 2] local segments.
    Returns ex, ey (closest point minus centre) and d2 (squared distance), each f32[R, W, Mc], and
    cross: bool[R, W, Mc], whether the +x ray from the centre crosses the segment.
    """
    ax, ay, bx, by = seg[:, 0, 0], seg[:, 0, 1], seg[:, 1, 0], seg[:, 1, 1]
    dx, dy = bx - ax, by - ay
    dd = dx * dx + dy * dy
    # Degenerate (zero-length) segments project onto their start point.
    t = ((px - ax) * dx + (py - ay) * dy) / jnp.where(dd > 0, dd, 1.0)
    t = jnp.clip(t, 0.0, 1.0)
    # Use the exact end points at t = 0 / 1 so a vertex shared by two segments gives equal distances
    # (then the first segment wins, as the conventions require).
    qx = jnp.where(t <= 0, ax, jnp.where(t >= 1, bx, ax + t * dx))
    qy = jnp.where(t <= 0, ay, jnp.where(t >= 1, by, ay + t * dy))
    ex, ey = qx - px, qy - py
    d2 = ex * ex + ey * ey
    # Even-odd rule, half-open in y so a ray through a vertex counts it exactly once.
    straddle = (ay > py) != (by > py)
    x_cross = ax + (py - ay) * dx / jnp.where(straddle, dy, 1.0)
    cross = straddle & (px < x_cross)
    return ex, ey, d2, cross


def _block_geometry(rows, seg_chunks, valid_chunks, width: int, cell_size):
    """Closest-boundary offset, squared distance and crossing parity for one block of rows.

    rows: i32[R]; seg_chunks: f32[C, Mc, 2, 2] (local frame); valid_chunks: bool[C, Mc].
    Returns (d2, ex, ey, parity), each [R, W].
    """
    py = ((rows.astype(jnp.float32) + 0.5) * cell_size)[:, None, None]
    px = ((jnp.arange(width, dtype=jnp.float32) + 0.5) * cell_size)[None, :, None]
    shape = (rows.shape[0], width)

    def step(carry, chunk):
        best_d2, best_ex, best_ey, parity = carry
        seg, valid = chunk
        ex, ey, d2, cross = _pair_terms(px, py, seg)
        d2 = jnp.where(valid, d2, jnp.inf)
        k = jnp.argmin(d2, axis=-1)[..., None]  # first index wins ties
        c_d2 = jnp.take_along_axis(d2, k, axis=-1)[..., 0]
        c_ex = jnp.take_along_axis(ex, k, axis=-1)[..., 0]
        c_ey = jnp.take_along_axis(ey, k, axis=-1)[..., 0]
        # Strictly better only: an earlier chunk (lower segment index) keeps exact ties.
        better = c_d2 < best_d2
        n_cross = jnp.sum(cross & valid, axis=-1)
        carry = (
            jnp.where(better, c_d2, best_d2),
            jnp.where(better, c_ex, best_ex),
            jnp.where(better, c_ey, best_ey),
            parity ^ (n_cross % 2 == 1),
        )
        return carry, None

    init = (
        jnp.full(shape, jnp.inf, jnp.float32),
        jnp.zeros(shape, jnp.float32),
        jnp.zeros(shape, jnp.float32),
        jnp.zeros(shape, bool),
    )
    out, _ = lax.scan(step, init, (seg_chunks, valid_chunks))
    return out


def _chunk_segments(seg, seg_chunk: int):
    """Pad ``seg: f32[M, 2, 2]`` to whole chunks: ``f32[C, Mc, 2, 2]`` and a validity ``bool[C, Mc]``."""
    m = seg.shape[0]
    mc = max(1, min(m, seg_chunk))
    n_chunks = -(-m // mc)
    pad = n_chunks * mc - m
    seg = jnp.pad(seg, ((0, pad), (0, 0), (0, 0)))
    valid = jnp.arange(n_chunks * mc) < m
    return seg.reshape(n_chunks, mc, 2, 2), valid.reshape(n_chunks, mc)


def _geometry_cells(segments, shape, *args, **kwargs) -> int:
    return int(shape[0]) * int(shape[1])


# the process's first compilation, usually: on the paper's grids the older code generator keeps the
# newer one's compiler (and its memory) out of the process
@functools.partial(grid_jit, static_argnames=("shape", "pair_budget", "seg_chunk"), cells_of=_geometry_cells)
def _geometry(segments, shape, cell_size, origin, pair_budget: int = _PAIR_BUDGET,
              seg_chunk: int = _SEG_CHUNK):
    """Target mask, distance and boundary direction of every cell (conventions, "Grid and geometry").

    segments: f32[M, 2, 2] from :func:`_segments`, world units (M >= 1).
    shape: static (H, W). cell_size: f32[], world units. origin: f32[2], world (x, y) of the grid corner.
    pair_budget / seg_chunk: static memory bounds (pairs live at once; segments per chunk).

    Returns
      target_mask: bool[H, W], centre covered by the target (even-odd rule, or within 1e-9 s of ∂T);
      dist: f32[H, W], world units, distance to the closest boundary segment, 0 on target cells;
      tvec: f32[H, W, 2], unit (x, y) vector to the closest boundary point, (0, 0) on target cells.

    Compiles once per (H, W, M) (and memory bounds); cell_size and origin are traced.
    """
    h, w = (int(v) for v in shape)
    cell_size = jnp.asarray(cell_size, jnp.float32)
    origin = jnp.asarray(origin, jnp.float32)
    # Work relative to the grid corner: small coordinates keep float32 rounding small.
    seg = jnp.asarray(segments, jnp.float32) - origin
    seg_chunks, valid_chunks = _chunk_segments(seg, seg_chunk)
    mc = seg_chunks.shape[1]
    rows_per_block = int(min(h, max(1, pair_budget // max(1, w * mc))))
    n_blocks = -(-h // rows_per_block)
    row_blocks = jnp.arange(n_blocks * rows_per_block, dtype=jnp.int32).reshape(n_blocks, -1)

    def block(rows):
        return _block_geometry(rows, seg_chunks, valid_chunks, w, cell_size)

    _, ex, ey, parity = (a.reshape(-1, w)[:h] for a in lax.map(block, row_blocks))
    # Distance and direction both come from the selected offset, so tvec has unit norm even where
    # XLA evaluated the argmin's squared distances with different rounding (e.g. fused multiply-add).
    dist = jnp.sqrt(ex * ex + ey * ey)
    mask = parity | (dist <= _ON_BOUNDARY_EPS * cell_size)
    safe = jnp.where(dist > 0, dist, 1.0)
    tvec = jnp.stack([ex / safe, ey / safe], axis=-1)
    tvec = jnp.where(mask[..., None], 0.0, tvec)
    dist = jnp.where(mask, 0.0, dist)
    return mask, dist, tvec


# --------------------------------------------------------------------------------------------------
# Validation (always at the Python level, before any JAX call)
# --------------------------------------------------------------------------------------------------

def _first_index(bad: np.ndarray) -> str:
    r, c = np.argwhere(bad)[0]
    return f"first at row {int(r)}, col {int(c)}"


def _validate_obj(obj) -> np.ndarray:
    """``obj`` as ``f32[H, W]`` numpy, or ValueError naming ``Scene.obj``."""
    try:
        arr = np.asarray(obj)
    except Exception as exc:  # e.g. ragged nested lists
        raise ValueError(f"Scene.obj: could not be read as an array ({exc}). Pass a 2-D array of "
                         "counts, rows = y, columns = x.") from None
    if arr.dtype.kind not in "biuf":
        raise ValueError(f"Scene.obj: counts must be numbers; got dtype {arr.dtype}. Pass a 2-D "
                         "float or integer array.")
    if arr.ndim != 2:
        raise ValueError(f"Scene.obj: must be 2-D [H, W] (rows = y, columns = x); got shape "
                         f"{arr.shape}. Reshape it to the grid.")
    if arr.shape[0] == 0 or arr.shape[1] == 0:
        raise ValueError(f"Scene.obj: the grid is empty (shape {arr.shape}); it needs at least one "
                         "row and one column.")
    arr = arr.astype(np.float64)
    for bad, what, fix in (
        (np.isnan(arr), "NaN", "Replace them with 0 or a measured count."),
        (np.isinf(arr), "infinite", "Replace them with a finite count."),
        (arr < 0, "negative", "Counts cannot be negative; clip them to 0."),
        (np.isfinite(arr) & (arr > _F32_MAX), "too-large (over float32 range)",
         "Rescale the counts."),
    ):
        if bad.any():
            raise ValueError(f"Scene.obj: counts must be finite and >= 0; found {int(bad.sum())} "
                             f"{what} value(s) ({_first_index(bad)}). {fix}")
    return arr.astype(np.float32)


def _validate_cell_size(cell_size) -> np.float32:
    try:
        value = float(cell_size)
    except (TypeError, ValueError):
        raise ValueError(f"Scene.cell_size: must be a number (world units per cell), got "
                         f"{cell_size!r}.") from None
    f32 = np.float32(value) if math.isfinite(value) and abs(value) <= _F32_MAX else np.float32(np.nan)
    if not (math.isfinite(value) and value > 0 and np.isfinite(f32) and f32 > 0):
        raise ValueError(f"Scene.cell_size: must be finite and > 0 (world units per cell), got "
                         f"{value!r}. Pass the side length of one grid cell, e.g. 1.0.")
    return f32


def _validate_origin(origin) -> np.ndarray:
    try:
        arr = np.asarray(origin, dtype=np.float64)
    except (TypeError, ValueError):
        arr = None
    if arr is None or arr.shape != (2,) or not np.all(np.isfinite(arr)) \
            or np.any(np.abs(arr) > _F32_MAX):
        raise ValueError(f"Scene.origin: must be 2 finite numbers (x, y), the world position of "
                         f"the grid's lower corner (cell (0, 0) starts there); got {origin!r}.")
    return arr.astype(np.float32)


def _validate_target(target):
    if not isinstance(target, (Polygon, MultiPolygon)):
        raise ValueError(f"Scene.target: must be a shapely Polygon or MultiPolygon in world units; "
                         f"got {type(target).__name__}. Build one with jaxplan.transport.scene.circle/box or "
                         "shapely.geometry.Polygon.")
    if target.is_empty:
        raise ValueError("Scene.target: the geometry is empty; give a polygon with non-zero area.")
    if not target.is_valid:
        raise ValueError(f"Scene.target: the geometry is invalid ({shapely.is_valid_reason(target)})."
                         " Fix the polygon (e.g. shapely.make_valid or target.buffer(0)) so that no "
                         "ring self-intersects and parts do not overlap.")
    if target.area <= 0:
        raise ValueError("Scene.target: the geometry has zero area; give a polygon with area.")
    return target


def _validate_name(name):
    if name is not None and not isinstance(name, str):
        raise ValueError(f"Scene.name: must be a str or None, got {type(name).__name__}.")
    return name


def _grid_extent(shape, cell_size, origin) -> Polygon:
    h, w = shape
    x0, y0 = float(origin[0]), float(origin[1])
    return _shapely_box(x0, y0, x0 + w * float(cell_size), y0 + h * float(cell_size))


def _check_target_on_grid(target, shape, cell_size, origin):
    extent = _grid_extent(shape, cell_size, origin)
    if not target.intersects(extent):
        raise ValueError(f"Scene.target: lies wholly outside the grid's extent {extent.bounds} "
                         f"(xmin, ymin, xmax, ymax); its bounds are {target.bounds}. Check origin, "
                         "cell_size and the target's units.")


def _check_target_covers_a_cell(mask, target, shape, cell_size):
    if not bool(np.asarray(mask).any()):
        raise ValueError(f"Scene.target: covers no cell centre of the {shape[0]}x{shape[1]} grid "
                         f"(cell_size {float(cell_size)}); bounds {target.bounds}. Enlarge or move "
                         "the target, or use a smaller cell_size.")


def _is_tracer(x) -> bool:
    return isinstance(x, jax.core.Tracer)


# --------------------------------------------------------------------------------------------------
# Scene
# --------------------------------------------------------------------------------------------------

_LEAVES = ("obj", "target_mask", "dist", "tvec", "cell_size", "origin")


@jax.tree_util.register_pytree_with_keys_class
class Scene:
    """An aggregate-count grid and a target region, with per-cell geometry. Immutable; a JAX pytree.

    Array leaves (pytree children, in this order):
      obj: f32[H, W], aggregate count per cell (rows = y, columns = x), >= 0.
      target_mask: bool[H, W], True where the cell centre is covered by the target.
      dist: f32[H, W], world units, ``d(C, T)``: distance from the centre to the target, 0 on target
        cells.
      tvec: f32[H, W, 2], unit (x, y) vector from the centre to the closest point of ``∂T``; (0, 0) on
        target cells.
      cell_size: f32[], world units per cell side.
      origin: f32[2], world (x, y) of the grid corner; cell (r, c) has centre
        ``origin + ((c + 0.5) s, (r + 0.5) s)``.

    Non-leaf attributes (plain Python, NOT in the pytree):
      target: the shapely Polygon/MultiPolygon (world units) the geometry was computed from.
      name: str or None.
    The pytree's aux data is ``None``, so ``jit`` never recompiles for a different target or name.
    The price: a Scene rebuilt from leaves (inside ``jit``/``vmap``, or by ``jax.tree.map``) has
    ``target = None`` and ``name = None``; its arrays are complete, so kernels never need them.

    Build scenes with :meth:`from_arrays`, :func:`builtin_scene` or :meth:`load`; the raw constructor
    does no validation.
    """

    __slots__ = _LEAVES + ("target", "name")

    def __init__(self, obj, target_mask, dist, tvec, cell_size, origin, target=None, name=None):
        values = dict(obj=obj, target_mask=target_mask, dist=dist, tvec=tvec, cell_size=cell_size,
                      origin=origin, target=target, name=name)
        for key, value in values.items():
            object.__setattr__(self, key, value)

    def __setattr__(self, key, value):
        raise AttributeError(f"Scene is immutable; cannot set {key!r}. Use with_obj or from_arrays.")

    def __delattr__(self, key):
        raise AttributeError(f"Scene is immutable; cannot delete {key!r}.")

    # -- pytree --------------------------------------------------------------------------------

    def tree_flatten_with_keys(self):
        return tuple((jax.tree_util.GetAttrKey(k), getattr(self, k)) for k in _LEAVES), None

    def tree_flatten(self):
        return tuple(getattr(self, k) for k in _LEAVES), None

    @classmethod
    def tree_unflatten(cls, aux, children):
        del aux  # always None: target and name are deliberately not carried (see class docstring)
        return cls(*children)

    # -- construction ------------------------------------------------------------------------

    @classmethod
    def from_arrays(cls, obj, target, cell_size=1.0, origin=(0.0, 0.0), name=None) -> Scene:
        """Validate the inputs and compute ``target_mask``, ``dist``, ``tvec`` with the JAX kernel.

        obj: [H, W] counts (array-like, finite, >= 0; rows = y, columns = x).
        target: shapely Polygon/MultiPolygon, world units; must be valid and cover >= 1 cell centre.
        cell_size: world units per cell, > 0. origin: world (x, y) of the grid corner.
        Raises ValueError naming the offending field.
        """
        obj = _validate_obj(obj)
        cell_size = _validate_cell_size(cell_size)
        origin = _validate_origin(origin)
        target = _validate_target(target)
        name = _validate_name(name)
        shape = tuple(int(v) for v in obj.shape)
        _check_target_on_grid(target, shape, cell_size, origin)
        mask, dist, tvec = _geometry(jnp.asarray(_segments(target)), shape,
                                     jnp.asarray(cell_size), jnp.asarray(origin))
        _check_target_covers_a_cell(mask, target, shape, cell_size)
        return cls(jnp.asarray(obj), mask, dist, tvec, jnp.asarray(cell_size), jnp.asarray(origin),
                   target=target, name=name)

    def with_obj(self, obj) -> Scene:
        """The same geometry with new counts ``obj: [H, W]`` (same shape).

        Concrete counts are validated like :meth:`from_arrays`; traced ones (inside ``jit``) cannot
        be inspected and are only shape-checked.
        """
        if _is_tracer(obj):
            if tuple(obj.shape) != self.shape:
                raise ValueError(f"Scene.obj: new counts have shape {tuple(obj.shape)} but the "
                                 f"scene's grid is {self.shape}.")
            new = jnp.asarray(obj, jnp.float32)
        else:
            new = _validate_obj(obj)
            if new.shape != self.shape:
                raise ValueError(f"Scene.obj: new counts have shape {new.shape} but the scene's "
                                 f"grid is {self.shape}. Build a new scene with Scene.from_arrays "
                                 "for a different grid.")
            new = jnp.asarray(new)
        return Scene(new, self.target_mask, self.dist, self.tvec, self.cell_size, self.origin,
                     target=self.target, name=self.name)

    # -- derived quantities ------------------------------------------------------------------

    @property
    def shape(self) -> tuple[int, int]:
        """(H, W), the grid shape (static, also inside ``jit``)."""
        return tuple(int(v) for v in self.obj.shape)

    def cell_centers(self):
        """f32[H, W, 2], world (x, y) centre of every cell."""
        h, w = self.shape
        cs = jnp.asarray(self.cell_size, jnp.float32)
        origin = jnp.asarray(self.origin, jnp.float32)
        xs = (jnp.arange(w, dtype=jnp.float32) + 0.5) * cs + origin[0]
        ys = (jnp.arange(h, dtype=jnp.float32) + 0.5) * cs + origin[1]
        x, y = jnp.meshgrid(xs, ys)
        return jnp.stack([x, y], axis=-1)

    @property
    def occupied(self):
        """bool[H, W], occupied cells: not a target cell and ``obj > 0``."""
        return ~self.target_mask & (self.obj > 0)

    @property
    def total_mass(self):
        """f32[], sum of ``obj`` over all cells (target cells included)."""
        return jnp.sum(self.obj)

    def __repr__(self) -> str:
        h, w = self.shape
        name = f"{self.name!r}, " if self.name is not None else ""
        kind = type(self.target).__name__ if self.target is not None else "None"
        return f"Scene({name}{h}x{w}, cell_size={self.cell_size}, target={kind})"

    # -- files -------------------------------------------------------------------------------

    def save(self, path) -> Path:
        """Write the scene to ``path`` (``.npz`` or ``.json``, by suffix); see docs/scene-format.md."""
        path = Path(path)
        suffix = _format_of(path)
        if self.target is None:
            raise ValueError("Scene.target: this scene has no shapely target (it was rebuilt from "
                             "pytree leaves, e.g. inside jit), so it cannot be saved.")
        if max(self.shape) > MAX_FILE_SIDE:
            raise ValueError(f"Scene.obj: the grid is {self.shape[0]} x {self.shape[1]}; a scene file "
                             f"holds at most {MAX_FILE_SIDE} x {MAX_FILE_SIDE} cells (MAX_FILE_SIDE), so "
                             "Scene.load could not read it back. Use a coarser cell_size.")
        obj = np.asarray(self.obj, np.float32)
        cell_size = float(np.asarray(self.cell_size))
        origin = [float(v) for v in np.asarray(self.origin)]
        wkt = _to_wkt(self.target)
        if suffix == ".npz":
            np.savez(path, format_version=np.int64(FORMAT_VERSION), obj=obj,
                     cell_size=np.float64(cell_size), origin=np.asarray(origin, np.float64),
                     target_wkt=np.str_(wkt),
                     name=np.str_(self.name) if self.name is not None else np.zeros(0, np.str_))
        else:
            doc = {"format_version": FORMAT_VERSION, "name": self.name, "cell_size": cell_size,
                   "origin": origin, "obj": obj.astype(np.float64).tolist(), "target": wkt}
            path.write_text(json.dumps(doc))
        return path

    @classmethod
    def load(cls, path) -> Scene:
        """Read a scene written by :meth:`save` (``.npz`` or ``.json``) and re-validate it.

        Every problem with the file -- unreadable, damaged, wrong keys or types, bad values -- raises
        one ``ValueError("Scene file <path>: <what is wrong>; <fix>")``; the checks are listed in
        docs/scene-format.md ("What is checked when a file is read").
        """
        path = Path(path)
        fields = _read_scene_file(path, _format_of(path))
        try:
            target = _parse_wkt(fields["target"])
            return cls.from_arrays(fields["obj"], target, cell_size=fields["cell_size"],
                                   origin=fields["origin"], name=fields["name"])
        except ValueError as exc:
            message = str(exc)
            message = message[len("Scene."):] if message.startswith("Scene.") else message
            raise ValueError(f"Scene file {path}: {message}") from None


def _ring_wkt(ring) -> str:
    return "(" + ", ".join(f"{x!r} {y!r}" for x, y, *_ in ring.coords) + ")"


def _polygon_wkt(poly) -> str:
    return "(" + ", ".join(_ring_wkt(r) for r in [poly.exterior, *poly.interiors]) + ")"


def _to_wkt(target) -> str:
    """2-D WKT with every coordinate as Python's shortest round-trip repr.

    shapely.to_wkt rounds some coordinates in the last bit even at full precision; repr + GEOS's
    parser round-trips exactly, so a loaded scene has bit-identical geometry.
    """
    if isinstance(target, MultiPolygon):
        return "MULTIPOLYGON (" + ", ".join(_polygon_wkt(p) for p in target.geoms) + ")"
    return "POLYGON " + _polygon_wkt(target)


def _format_of(path: Path) -> str:
    suffix = path.suffix.lower()
    if suffix not in (".npz", ".json"):
        raise ValueError(f"Scene file {path}: unknown suffix {path.suffix!r}; use '.npz' or '.json'.")
    return suffix


class _FileProblem(ValueError):
    """What is wrong with a scene file, as ``"<what>; <fix>"``; :func:`_read_scene_file` adds the path."""


# What a broken file makes the decoders raise (a truncated or corrupted zip, binary noise, a .npy
# header that lies): each becomes one ValueError naming the file instead of a traceback.
_DECODE_ERRORS = (zipfile.BadZipFile, zlib.error, EOFError, struct.error, UnicodeDecodeError, ValueError,
                  KeyError, TypeError, IndexError, OverflowError, RecursionError, MemoryError,
                  NotImplementedError, SyntaxError, tokenize.TokenError)   # the last two: a damaged .npy header


def _read_scene_file(path: Path, suffix: str) -> dict:
    """The raw fields of a scene file (format_version checked, types checked, values not yet).

    Returns ``{"obj": f64/f32[H, W], "cell_size": float, "origin": f64[2], "target": str (WKT),
    "name": str | None}``. Raises ValueError ``"Scene file <path>: <what>; <fix>"``.
    """
    kind = "a NumPy .npz archive" if suffix == ".npz" else "JSON text (UTF-8)"
    try:
        if path.is_dir():
            raise _FileProblem(f"is a directory; give the path of a {suffix} scene file")
        if path.stat().st_size == 0:
            raise _FileProblem(f"is empty (0 bytes); a scene file is {kind} written by Scene.save")
        return _read_npz(path) if suffix == ".npz" else _read_json(path)
    except _FileProblem as exc:
        raise ValueError(f"Scene file {path}: {exc}.") from None
    except FileNotFoundError:
        raise ValueError(f"Scene file {path}: no such file; check the path.") from None
    except OSError as exc:  # permissions, a device error, ...
        raise ValueError(f"Scene file {path}: could not be read ({exc.strerror or exc}); check the "
                         "file's permissions.") from None
    except _DECODE_ERRORS as exc:
        raise ValueError(f"Scene file {path}: is not {kind} or is damaged ({type(exc).__name__}: "
                         f"{exc}); write scene files with Scene.save (docs/scene-format.md).") from None


def _check_keys(keys, allowed: tuple, optional: tuple = ()) -> None:
    """Refuse unknown keys (naming them and the allowed ones) and missing required keys."""
    unknown = [k for k in keys if k not in allowed]
    if unknown:
        raise _FileProblem(f"unknown key(s) {', '.join(map(repr, unknown))}; a scene file has exactly the "
                           f"keys {', '.join(allowed)} (docs/scene-format.md)")
    missing = [k for k in allowed if k not in keys and k not in optional]
    if missing:
        raise _FileProblem(f"missing key(s) {', '.join(missing)}; see docs/scene-format.md")


def _check_version(version) -> None:
    if version != FORMAT_VERSION:
        raise _FileProblem(f"format_version is {version!r}; this version of jaxplan reads format_version "
                           f"{FORMAT_VERSION} only")


def _check_grid_shape(shape) -> None:
    """``obj``'s shape, checked before its data is read: 2-D and at most MAX_FILE_SIDE a side."""
    if len(shape) != 2:
        raise _FileProblem(f"obj: must be 2-D [H, W] (rows = y, columns = x); got shape {tuple(shape)}")
    if max(shape) > MAX_FILE_SIDE:
        raise _FileProblem(f"obj: the grid is {shape[0]} x {shape[1]}; a scene file holds at most "
                           f"{MAX_FILE_SIDE} x {MAX_FILE_SIDE} cells. Use a coarser cell_size")


# --------------------------------------------------------------------------------------------------
# .npz
# --------------------------------------------------------------------------------------------------

_NPZ_KEYS = ("format_version", "obj", "cell_size", "origin", "target_wkt", "name")

# key -> (allowed dtype kinds, allowed shapes (None: any), what the key must hold)
_NPZ_FIELDS = {
    "format_version": ("iu", ((),), f"an integer scalar ({FORMAT_VERSION})"),
    "obj": ("iuf", None, "a 2-D array of numbers (float32 counts)"),
    "cell_size": ("iuf", ((),), "a number scalar (world units per cell side)"),
    "origin": ("iuf", ((2,),), "2 numbers (x, y)"),
    "target_wkt": ("U", ((),), "a string scalar (WKT)"),
    "name": ("U", ((), (0,)), "a string scalar, or an empty (0,) array for no name"),
}


def _npy_header(zf: zipfile.ZipFile, key: str):
    """(shape, dtype) of the archive member ``<key>.npy``, read from its header only."""
    with zf.open(f"{key}.npy") as fp:
        version = np.lib.format.read_magic(fp)
        if version == (1, 0):
            shape, _, dtype = np.lib.format.read_array_header_1_0(fp)
        elif version == (2, 0):
            shape, _, dtype = np.lib.format.read_array_header_2_0(fp)
        else:
            raise _FileProblem(f"{key}: .npy format version {version} is not supported; save with "
                               "numpy.savez")
    return shape, dtype


def _npz_array(zf: zipfile.ZipFile, key: str) -> np.ndarray:
    """The member ``<key>.npy``, its dtype and shape checked (from the header) before reading it."""
    shape, dtype = _npy_header(zf, key)
    kinds, shapes, what = _NPZ_FIELDS[key]
    if dtype.hasobject:
        raise _FileProblem(f"{key}: is an object (pickled) array, which is never loaded "
                           f"(allow_pickle=False); store {what}")
    if key == "obj":
        _check_grid_shape(shape)
    empty_name = key == "name" and shape == (0,)
    if (dtype.kind not in kinds and not empty_name) or (shapes is not None and shape not in shapes):
        raise _FileProblem(f"{key}: holds dtype {dtype} with shape {shape}; it must hold {what}")
    with zf.open(f"{key}.npy") as fp:
        return np.lib.format.read_array(fp, allow_pickle=False)


def _read_npz(path: Path) -> dict:
    with zipfile.ZipFile(path) as zf:
        members = zf.namelist()
        odd = [m for m in members if not m.endswith(".npy")]
        if odd:
            raise _FileProblem(f"holds {odd[0]!r}, which is not a .npy array; a scene archive holds "
                               f"only the arrays {', '.join(_NPZ_KEYS)}")
        keys = [m[:-len(".npy")] for m in members]
        if "format_version" in keys:  # first: another version may have other keys
            _check_version(int(_npz_array(zf, "format_version")))
        _check_keys(keys, _NPZ_KEYS)
        arrays = {key: _npz_array(zf, key) for key in _NPZ_KEYS}
    name = arrays["name"]
    return {
        "obj": arrays["obj"],
        "cell_size": float(arrays["cell_size"]),
        "origin": arrays["origin"].astype(np.float64),
        "target": str(arrays["target_wkt"]),
        "name": str(name) if name.ndim == 0 else None,
    }


# --------------------------------------------------------------------------------------------------
# .json
# --------------------------------------------------------------------------------------------------

_JSON_KEYS = ("format_version", "name", "cell_size", "origin", "obj", "target")


def _is_number(v) -> bool:
    """A JSON number: int or float, not a bool (``True`` is an int in Python)."""
    return type(v) in (int, float)


def _json_type(v) -> str:
    if v is None:
        return "null"
    kind = {bool: "a boolean", str: "a string", list: "a list", dict: "an object"}.get(type(v), "a number")
    return f"{kind} ({json.dumps(v)[:40]})"


def _json_obj(rows) -> np.ndarray:
    """``obj`` from its JSON rows: f64[H, W]; names the first bad row or cell."""
    if not isinstance(rows, list) or not rows:
        raise _FileProblem(f"obj: must be a non-empty list of H rows, each a list of W numbers; got "
                           f"{_json_type(rows)}")
    width = len(rows[0]) if isinstance(rows[0], list) else 0
    _check_grid_shape((len(rows), width))
    for r, row in enumerate(rows):
        if not isinstance(row, list):
            raise _FileProblem(f"obj: row {r} is {_json_type(row)}, not a list of numbers")
        if len(row) != width:
            raise _FileProblem(f"obj: row {r} has {len(row)} value(s) but row 0 has {width}; every "
                               "row needs the same length W")
        if not all(map(_is_number, row)):
            c = next(c for c, v in enumerate(row) if not _is_number(v))
            hint = " (obj must be 2-D: one number per cell)" if isinstance(row[c], list) else ""
            raise _FileProblem(f"obj: row {r}, column {c} is {_json_type(row[c])}; counts must be "
                               f"numbers{hint}")
    try:
        return np.array(rows, np.float64)
    except OverflowError:  # an integer beyond float64
        raise _FileProblem("obj: holds an integer too large for a float; rescale the counts") from None


def _read_json(path: Path) -> dict:
    raw = path.read_bytes()
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise _FileProblem(f"is not UTF-8 text (byte {exc.start}: {exc.reason}), so not a JSON scene "
                           "file; a binary scene file must be named .npz") from None
    try:
        doc = json.loads(text)
    except json.JSONDecodeError as exc:
        raise _FileProblem(f"not valid JSON ({exc})") from None
    if not isinstance(doc, dict):
        raise _FileProblem(f"the top level must be a JSON object with the keys {', '.join(_JSON_KEYS)}; "
                           f"got {_json_type(doc)}")
    if "format_version" in doc:  # first: another version may have other keys
        version = doc["format_version"]
        if type(version) is not int:
            raise _FileProblem(f"format_version: must be the integer {FORMAT_VERSION}; got "
                               f"{_json_type(version)}")
        _check_version(version)
    _check_keys(list(doc), _JSON_KEYS, optional=("name",))
    cell_size, origin, target, name = (doc.get(k) for k in ("cell_size", "origin", "target", "name"))
    if not _is_number(cell_size):
        raise _FileProblem(f"cell_size: must be a number (world units per cell side); got "
                           f"{_json_type(cell_size)}")
    if not (isinstance(origin, list) and len(origin) == 2 and all(map(_is_number, origin))):
        raise _FileProblem(f"origin: must be a list of 2 numbers [x, y]; got {_json_type(origin)}")
    if not isinstance(target, str):
        raise _FileProblem(f"target: must be a WKT string (POLYGON or MULTIPOLYGON); got "
                           f"{_json_type(target)}")
    if name is not None and not isinstance(name, str):
        raise _FileProblem(f"name: must be a string or null; got {_json_type(name)}")
    return {"obj": _json_obj(doc["obj"]), "cell_size": float(cell_size),
            "origin": np.asarray(origin, np.float64), "target": target, "name": name}


def _parse_wkt(wkt: str):
    """The shapely geometry of ``wkt``; ValueError naming ``target`` when it does not parse."""
    try:
        geom = shapely.from_wkt(wkt)
    except Exception as exc:  # shapely raises its own GEOSException
        raise ValueError(f"target: could not parse the WKT ({exc}); give a POLYGON or MULTIPOLYGON, "
                         "e.g. 'POLYGON ((0 0, 1 0, 1 1, 0 1, 0 0))'.") from None
    if geom is None:
        raise ValueError("target: the WKT is empty; give a POLYGON or MULTIPOLYGON.")
    return geom


def stack_scenes(scenes) -> Scene:
    """One Scene pytree whose leaves are those of ``scenes`` (one grid shape, one cell size) stacked
    on a new leading axis: the input of ``jax.vmap`` over scenes."""
    return jax.tree.map(lambda *xs: jnp.stack([jnp.asarray(x) for x in xs]), *scenes)
