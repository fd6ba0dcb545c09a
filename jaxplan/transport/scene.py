"""The planning scene: an aggregate-count grid plus a target region, and its geometry fields.

A :class:`Scene` holds the occupancy grid of Section 2 (``obj``) together with the per-cell geometry
every later kernel needs (Section 3.1): which cells are target cells, the distance ``d(C, T)`` and the
unit vector ``t(C)`` toward the target boundary. Exact definitions are in ``docs/transport.md``
("Grid and geometry"); the file formats of :meth:`Scene.save` are in ``docs/scene-files.md``.

The geometry kernel is :func:`jaxplan.transport.geometry.target_geometry`; the files are read and
written by :mod:`jaxplan.transport.scene_files`. Inputs are validated here, at the Python level,
before any JAX call.
"""
from __future__ import annotations

import math
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import shapely
from shapely.geometry import MultiPolygon, Polygon
from shapely.geometry import box as _shapely_box

from jaxplan.transport.geometry import box, circle, target_geometry, target_segments
from jaxplan.transport.obstacles import NO_DETOUR, obstacle_geometry
from jaxplan.transport.scene_files import (
    FORMAT_VERSION,
    MAX_FILE_SIDE,
    read_scene_file,
    scene_file_format,
    write_scene_file,
)

__all__ = ["FORMAT_VERSION", "MAX_FILE_SIDE", "Scene", "box", "circle", "occupied_cells", "stack_scenes"]

_F32_MAX = float(np.finfo(np.float32).max)


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


def _validate_blocked(blocked, shape) -> np.ndarray:
    """``blocked`` as ``bool[H, W]`` numpy (all False for None), or ValueError naming ``Scene.blocked``."""
    if blocked is None:
        return np.zeros(shape, bool)
    try:
        arr = np.asarray(blocked)
    except Exception as exc:  # e.g. ragged nested lists
        raise ValueError(f"Scene.blocked: could not be read as an array ({exc}). Pass a bool [H, W] mask, "
                         "True on buildings and no-go cells.") from None
    if arr.shape != tuple(shape):
        raise ValueError(f"Scene.blocked: shape {arr.shape} disagrees with Scene.obj's {tuple(shape)}; pass one "
                         "bool per cell, rows = y, columns = x.")
    if arr.dtype != bool:
        if arr.dtype.kind not in "biu" or not np.isin(arr, (0, 1)).all():
            raise ValueError(f"Scene.blocked: must be a bool mask (or 0/1); got dtype {arr.dtype}. Pass True on "
                             "blocked cells and False elsewhere.")
        arr = arr.astype(bool)
    return arr


def _check_blocked_cells(blocked, obj, mask) -> None:
    for bad, what, fix in (
        (blocked & (obj > 0), "material", "Move the material to a free cell or unblock the cell."),
        (blocked & np.asarray(mask), "target area", "Move the target off the blocked cells or unblock them."),
    ):
        if bad.any():
            raise ValueError(f"Scene.blocked: {int(bad.sum())} blocked cell(s) hold {what} ({_first_index(bad)}). "
                             f"{fix}")


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


def _check_leaf_shapes(scene) -> None:
    """ValueError naming the first leaf whose shape disagrees with ``obj: [H, W]``. Shapes are static,
    so this also holds for traced leaves (inside ``jit``/``vmap``)."""
    shape = tuple(np.shape(scene.obj))
    if len(shape) != 2 or 0 in shape:
        raise ValueError(f"Scene.obj: must be a non-empty 2-D grid [H, W] (rows = y, columns = x); got shape "
                         f"{shape}. Build scenes with Scene.from_arrays(obj, target).")
    wanted = dict(target_mask=shape, dist=shape, tvec=shape + (2,), cell_size=(), origin=(2,), blocked=shape,
                  detour=shape)
    for field, want in wanted.items():
        got = tuple(np.shape(getattr(scene, field)))
        if got != want:
            raise ValueError(f"Scene.{field}: shape {got} disagrees with Scene.obj's {shape}; it must be {want}. "
                             "Build the scene with Scene.from_arrays(obj, target) (or scene.with_obj(obj) for "
                             "new counts), which computes target_mask, dist and tvec for obj's grid.")


# --------------------------------------------------------------------------------------------------
# Scene
# --------------------------------------------------------------------------------------------------

_LEAVES = ("obj", "target_mask", "dist", "tvec", "cell_size", "origin", "blocked", "detour")


@jax.tree_util.register_pytree_with_keys_class
class Scene:
    """An aggregate-count grid and a target region, with per-cell geometry. Immutable; a JAX pytree.

    Array leaves (pytree children, in this order):
      obj: f32[H, W], aggregate count per cell (rows = y, columns = x), >= 0.
      target_mask: bool[H, W], True where the cell centre is covered by the target.
      dist: f32[H, W], world units, ``d(C, T)``: distance from the centre to the target, 0 on target
        cells; around blocked cells the geodesic distance, +inf on blocked cells and on free cells cut
        off from every target (``jaxplan.transport.obstacles``).
      tvec: f32[H, W, 2], unit (x, y) vector from the centre to the closest point of ``∂T`` (around
        blocked cells, along the first step of the detour); (0, 0) on target, blocked and cut-off cells.
      cell_size: f32[], world units per cell side.
      origin: f32[2], world (x, y) of the grid corner; cell (r, c) has centre
        ``origin + ((c + 0.5) s, (r + 0.5) s)``.
      blocked: bool[H, W], buildings, equipment and no-go cells: no route, rover or material enters them.
      detour: i32[H, W], the first step's direction (0-7) of a cell whose straight way to the target is
        blocked, ``obstacles.NO_DETOUR`` (-1) elsewhere.

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

    def __init__(self, obj, target_mask, dist, tvec, cell_size, origin, blocked=None, detour=None, target=None,
                 name=None):
        if blocked is None and detour is None and np.ndim(obj) == 2:   # a scene without blocked cells
            blocked = jnp.zeros(np.shape(obj), bool)
            detour = jnp.full(np.shape(obj), NO_DETOUR, jnp.int32)
        values = dict(obj=obj, target_mask=target_mask, dist=dist, tvec=tvec, cell_size=cell_size,
                      origin=origin, blocked=blocked, detour=detour, target=target, name=name)
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
    def from_arrays(cls, obj, target, cell_size=1.0, origin=(0.0, 0.0), name=None, blocked=None) -> Scene:
        """Validate the inputs and compute ``target_mask``, ``dist``, ``tvec``, ``detour`` with the JAX kernels.

        obj: [H, W] counts (array-like, finite, >= 0; rows = y, columns = x).
        target: shapely Polygon/MultiPolygon, world units; must be valid and cover >= 1 cell centre.
        cell_size: world units per cell, > 0. origin: world (x, y) of the grid corner.
        blocked: optional bool [H, W], True on buildings and no-go cells; none may hold material or
        target area.
        Raises ValueError naming the offending field.
        """
        obj = _validate_obj(obj)
        cell_size = _validate_cell_size(cell_size)
        origin = _validate_origin(origin)
        target = _validate_target(target)
        name = _validate_name(name)
        shape = tuple(int(v) for v in obj.shape)
        blocked = _validate_blocked(blocked, shape)
        _check_target_on_grid(target, shape, cell_size, origin)
        mask, dist, tvec = target_geometry(jnp.asarray(target_segments(target)), shape,
                                           jnp.asarray(cell_size), jnp.asarray(origin))
        _check_target_covers_a_cell(mask, target, shape, cell_size)
        _check_blocked_cells(blocked, obj, mask)
        if blocked.any():
            dist, tvec, detour = obstacle_geometry(blocked, mask, dist, tvec, jnp.asarray(cell_size))
        else:   # every cell is clear: the straight-line geometry stands
            detour = jnp.full(shape, NO_DETOUR, jnp.int32)
        return cls(jnp.asarray(obj), mask, dist, tvec, jnp.asarray(cell_size), jnp.asarray(origin),
                   jnp.asarray(blocked), detour, target=target, name=name)

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
            if np.any(np.asarray(self.blocked) & (new > 0)):
                _check_blocked_cells(np.asarray(self.blocked), new, np.zeros(new.shape, bool))
            new = jnp.asarray(new)
        return Scene(new, self.target_mask, self.dist, self.tvec, self.cell_size, self.origin, self.blocked,
                     self.detour, target=self.target, name=self.name)

    @classmethod
    def check(cls, scene, argument: str = "scene", *, counts: bool = True) -> None:
        """Check an entry point's ``scene`` argument before any JAX call (the raw constructor, the
        pytree's unflatten, checks nothing).

        Raises ``TypeError`` naming ``argument`` when ``scene`` is not a Scene (a name such as
        ``"default"`` is loaded with ``builtin_scene``); ``ValueError`` naming the field when the
        leaves' shapes disagree with ``obj: [H, W]`` (``target_mask [H, W]``, ``dist [H, W]``,
        ``tvec [H, W, 2]``, ``cell_size []``, ``origin [2]``), and, with ``counts`` and concrete
        counts, when ``obj`` holds NaN, infinite, negative or non-numeric values (as
        :meth:`from_arrays`). Traced counts (inside ``jit``) are not inspected.
        """
        if not isinstance(scene, cls):
            hint = (f" Load a named scene with jaxplan.builtin_scene({scene!r}) or a file with Scene.load."
                    if isinstance(scene, str) else "")
            raise TypeError(f"{argument}: expected a Scene, got {type(scene).__name__}.{hint} Build one with "
                            "Scene.from_arrays(obj, target).")
        _check_leaf_shapes(scene)
        if counts and not _is_tracer(scene.obj):
            _validate_obj(scene.obj)

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
        """bool[H, W], occupied cells: not a target cell, ``obj > 0`` and a finite way to a target."""
        return occupied_cells(self.obj, self.target_mask, self.dist)

    @property
    def cut_off(self):
        """bool[H, W], free non-target cells with no way to any target (``dist = inf``)."""
        return ~self.target_mask & ~self.blocked & ~jnp.isfinite(self.dist)

    @property
    def unreachable_mass(self):
        """f32[], objects on cells cut off from every target: never planned."""
        return jnp.sum(jnp.where(self.cut_off, self.obj, 0.0))

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
        """Write the scene to ``path`` (``.npz`` or ``.json``, by suffix); see docs/scene-files.md."""
        path = Path(path)
        scene_file_format(path)
        if self.target is None:
            raise ValueError("Scene.target: this scene has no shapely target (it was rebuilt from "
                             "pytree leaves, e.g. inside jit), so it cannot be saved.")
        if max(self.shape) > MAX_FILE_SIDE:
            raise ValueError(f"Scene.obj: the grid is {self.shape[0]} x {self.shape[1]}; a scene file "
                             f"holds at most {MAX_FILE_SIDE} x {MAX_FILE_SIDE} cells (MAX_FILE_SIDE), so "
                             "Scene.load could not read it back. Use a coarser cell_size.")
        return write_scene_file(path, self)

    @classmethod
    def load(cls, path) -> Scene:
        """Read a scene written by :meth:`save` (``.npz`` or ``.json``) and re-validate it.

        Every problem with the file -- unreadable, damaged, wrong keys or types, bad values -- raises
        one ``ValueError("Scene file <path>: <what is wrong>; <fix>")``; the checks are listed in
        docs/scene-files.md ("What is checked when a file is read").
        """
        path = Path(path)
        try:
            fields = read_scene_file(path)
            return cls.from_arrays(fields["obj"], fields["target"], cell_size=fields["cell_size"],
                                   origin=fields["origin"], name=fields["name"], blocked=fields.get("blocked"))
        except ValueError as exc:
            message = str(exc)
            if message.startswith("Scene file "):   # the file reader names the file already
                raise ValueError(message) from None
            message = message[len("Scene."):] if message.startswith("Scene.") else message
            raise ValueError(f"Scene file {path}: {message}") from None


def occupied_cells(obj, target_mask, dist):
    """``bool[H, W]``: the cells a route can start from or pass through: not a target cell, ``obj >
    0``, and a finite ``dist`` (not cut off from every target by blocked cells)."""
    return ~jnp.asarray(target_mask, bool) & (jnp.asarray(obj) > 0) & jnp.isfinite(dist)


def stack_scenes(scenes) -> Scene:
    """One Scene pytree whose leaves are those of ``scenes`` (one grid shape, one cell size) stacked
    on a new leading axis: the input of ``jax.vmap`` over scenes."""
    return jax.tree.map(lambda *xs: jnp.stack([jnp.asarray(x) for x in xs]), *scenes)
