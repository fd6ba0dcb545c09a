"""The PushAround scene (Section II): workspace, fixed and movable obstacles, robots, vehicle, endpoints.

A :class:`PushScene` is immutable; :meth:`PushScene.with_poses` returns a copy with new movable poses
(what a physics rollout produces). ``PushScene.from_dict`` / ``load`` validate everything and raise
``ValueError`` naming the offending field and the fix; the JSON format is in ``docs/pusharound.md``.

Frames and units: metres, kilograms, radians. A movable's pieces are stored in its body frame (area
centroid at the origin); its pose ``(x, y, psi)`` places the centroid at ``(x, y)`` rotated by ``psi``
(counter-clockwise). Fixed obstacles are stored in world coordinates.
"""
from __future__ import annotations

import copy
import dataclasses
import json
import math
import numbers
from pathlib import Path

import numpy as np
import shapely
from shapely import affinity
from shapely.geometry import Point, Polygon
from shapely.geometry import box as _box

from jaxplan.core import read_text
from jaxplan.pusharound.shapes import convex_decomposition, is_convex, polygon_inertia

__all__ = ["FORMAT", "FORMAT_VERSION", "Fixed", "Movable", "PushScene", "check_fields", "validate_scene"]

FORMAT = "jaxplan.pusharound.scene"
FORMAT_VERSION = 1

# Two obstacles overlap when their intersection has more area than this [m^2]; touching is allowed.
_OVERLAP_AREA = 1e-9
# Largest workspace side and coordinate magnitude [m]: a construction site fits well inside, and the
# physics (MuJoCo, float64 geometry but float32 rendering and contact margins in mm) loses its
# precision far beyond it.
MAX_WORKSPACE_SIDE = 1000.0
MAX_COORDINATE = 10_000.0


@dataclasses.dataclass(frozen=True)
class Fixed:
    """An immovable obstacle: ``pieces`` are convex Polygons in world coordinates."""

    name: str
    pieces: tuple

    def __post_init__(self):
        label = f"Fixed({self.name!r})" if isinstance(self.name, str) else "Fixed"
        _set(self, "name", _check_name(self.name, label))
        _set(self, "pieces", _check_pieces(self.pieces, f"{label}.pieces"))

    @property
    def polygon(self) -> Polygon:
        return shapely.union_all(self.pieces)

    def world_pieces(self) -> tuple:
        return self.pieces


@dataclasses.dataclass(frozen=True)
class Movable:
    """A movable rigid polygon (Section II-A).

    pieces: convex Polygons in the body frame (centroid at the origin); pose: (x, y, psi) [m, m, rad];
    mass [kg] > 0; inertia [kg m^2] about the centroid (uniform lamina when built from a scene file
    without one); friction: Coulomb coefficient with the floor, >= 0; shape: how it was made
    (``{"kind": "cylinder", "radius": 0.3}``) or None.
    """

    name: str
    pieces: tuple
    pose: tuple
    mass: float
    inertia: float
    friction: float = 0.5
    shape: dict | None = None

    def __post_init__(self):
        label = f"Movable({self.name!r})" if isinstance(self.name, str) else "Movable"
        _set(self, "name", _check_name(self.name, label))
        _set(self, "pieces", _check_pieces(self.pieces, f"{label}.pieces"))
        _set(self, "pose", tuple(_numbers(self.pose, 3, f"{label}.pose", "[x, y, psi] (m, m, rad)")))
        for field, lo, unit in (("mass", "> 0", "kg"), ("inertia", "> 0", "kg m^2"), ("friction", ">= 0", "")):
            _set(self, field, _signed(getattr(self, field), f"{label}.{field}", lo, unit))
        if self.shape is not None and not isinstance(self.shape, dict):
            raise TypeError(f"{label}.shape: expected a dict such as {{'kind': 'cylinder', 'radius': 0.3}}, or None; "
                            f"got {_kind(self.shape)}.")

    def at(self, pose) -> Movable:
        """A copy at ``pose`` (x, y, psi) without checks: a rollout's pose is whatever the physics produced."""
        out = copy.copy(self)
        object.__setattr__(out, "pose", pose)
        return out

    def world_pieces(self, pose=None) -> tuple:
        x, y, psi = self.pose if pose is None else pose
        return tuple(affinity.translate(affinity.rotate(p, psi, origin=(0, 0), use_radians=True), x, y)
                     for p in self.pieces)

    @property
    def polygon(self) -> Polygon:
        """The outline in world coordinates (the body-frame union, moved: pieces share edges exactly
        there, whereas rotated pieces may not, and their union could split)."""
        x, y, psi = self.pose
        body = shapely.union_all(self.pieces)
        return affinity.translate(affinity.rotate(body, psi, origin=(0, 0), use_radians=True), x, y)


@dataclasses.dataclass(frozen=True)
class PushScene:
    """workspace: (x0, y0, x1, y1) [m]; width: vehicle width W [m] (the vehicle is a disk of radius
    W/2); start, goal: (x, y) of the vehicle; fixed, movables: tuples of :class:`Fixed` / :class:`Movable`;
    robots: f64[N, 2] robot positions; robot_radius [m]."""

    workspace: tuple
    width: float
    start: tuple
    goal: tuple
    fixed: tuple = ()
    movables: tuple = ()
    robots: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros((0, 2)))
    robot_radius: float = 0.15

    def __post_init__(self):
        """Check every field's type, shape, finiteness, sign and range (``TypeError`` / ``ValueError``
        naming the field and the fix), the same checks as a scene file's; :func:`validate_scene` adds
        the consistency of the objects (inside the workspace, no overlaps)."""
        for field, value in zip(_ARG_NAMES, check_fields(self.workspace, self.width, self.start, self.goal,
                                                         self.robots, self.robot_radius, _ARG_NAMES)):
            _set(self, field, value)
        for field, kind in (("fixed", Fixed), ("movables", Movable)):
            _set(self, field, _check_parts(getattr(self, field), kind, f"PushScene.{field}"))

    # ---------------------------------------------------------------- derived geometry
    @property
    def workspace_polygon(self) -> Polygon:
        return _box(*self.workspace)

    @property
    def poses(self) -> np.ndarray:
        """f64[M, 3] movable poses (x, y, psi)."""
        return np.asarray([m.pose for m in self.movables], np.float64).reshape(-1, 3)

    @property
    def masses(self) -> np.ndarray:
        return np.asarray([m.mass for m in self.movables], np.float64)

    def obstacle_polygons(self) -> list:
        """World outlines of all obstacles: movables first (index m), then fixed (index M + f)."""
        return [m.polygon for m in self.movables] + [f.polygon for f in self.fixed]

    def with_poses(self, poses) -> PushScene:
        """A copy with movable poses ``poses: f[M, 3]`` (no validation: a rollout may touch walls)."""
        poses = np.asarray(poses, np.float64).reshape(len(self.movables), 3)
        movables = tuple(m.at(tuple(float(v) for v in p)) for m, p in zip(self.movables, poses))
        return dataclasses.replace(self, movables=movables)

    def replace(self, **changes) -> PushScene:
        return dataclasses.replace(self, **changes)

    # ---------------------------------------------------------------- serialisation
    def to_dict(self) -> dict:
        def pieces(ps):
            return [[[float(x), float(y)] for x, y in np.asarray(p.exterior.coords)[:-1, :2]] for p in ps]

        return {
            "format": FORMAT, "version": FORMAT_VERSION,
            "workspace": [float(v) for v in self.workspace],
            "vehicle_width": float(self.width),
            "start": [float(v) for v in self.start], "goal": [float(v) for v in self.goal],
            "fixed": [{"name": f.name, "pieces": pieces(f.pieces)} for f in self.fixed],
            "movables": [{"name": m.name, "pieces": pieces(m.pieces), "pose": [float(v) for v in m.pose],
                          "mass": float(m.mass), "inertia": float(m.inertia),
                          "friction": float(m.friction),
                          **({"shape": m.shape} if m.shape else {})} for m in self.movables],
            "robots": {"positions": np.asarray(self.robots, float).tolist(),
                       "radius": float(self.robot_radius)},
        }

    def save(self, path) -> Path:
        path = Path(path)
        path.write_text(json.dumps(self.to_dict(), indent=1))
        return path

    @classmethod
    def load(cls, path) -> PushScene:
        """Read a scene file (the JSON format of ``docs/pusharound.md``) and validate it.

        Every problem -- missing, a directory, unreadable, empty, not UTF-8 JSON, wrong keys, types or
        values -- raises one ``ValueError("Scene file <path>: <what is wrong>; <fix>")``.
        """
        path = Path(path)
        try:
            data = _read_json_file(path)
            return cls.from_dict(data)
        except ValueError as exc:
            raise ValueError(f"Scene file {path}: {exc}") from None

    @classmethod
    def from_dict(cls, data: dict) -> PushScene:
        """Parse and validate a scene dictionary (the JSON format of ``docs/pusharound.md``).

        Raises ``ValueError`` naming the field (``movables[2].mass: ...``) for unknown or missing keys,
        values of the wrong type, non-finite numbers, bad polygons and an inconsistent scene.
        """
        if not isinstance(data, dict):
            raise ValueError(f"scene: expected a JSON object with the keys {', '.join(_TOP_KEYS)}; got "
                             f"{_kind(data)}.")
        _check_keys(data, _TOP_KEYS, "scene", required=("workspace", "vehicle_width", "start", "goal"))
        fmt, version = data.get("format", FORMAT), data.get("version", FORMAT_VERSION)
        if fmt != FORMAT or type(version) is not int or version != FORMAT_VERSION:
            raise ValueError(f"format/version: expected {FORMAT!r} version {FORMAT_VERSION}; got "
                             f"{fmt!r} version {version!r}.")
        ws = _floats(data["workspace"], 4, "workspace", "[x0, y0, x1, y1] in metres")
        fixed = tuple(_parse_fixed(f, i) for i, f in enumerate(_list(data.get("fixed", []), "fixed")))
        movables = tuple(_parse_movable(m, i) for i, m in enumerate(_list(data.get("movables", []), "movables")))
        rob = data.get("robots")
        rob = {} if rob is None else rob
        if not isinstance(rob, dict):
            raise ValueError(f"robots: expected an object with 'positions' and 'radius'; got {_kind(rob)}.")
        _check_keys(rob, ("positions", "radius"), "robots")
        positions = [_floats(p, 2, f"robots.positions[{k}]", "[x, y] in metres")
                     for k, p in enumerate(_list(rob.get("positions", []), "robots.positions"))]
        ws, width, start, goal, robots, radius = check_fields(
            ws, _scalar(data["vehicle_width"], "vehicle_width"), _floats(data["start"], 2, "start", "[x, y]"),
            _floats(data["goal"], 2, "goal", "[x, y]"), np.asarray(positions, np.float64).reshape(-1, 2),
            _scalar(rob.get("radius", 0.15), "robots.radius"), _FILE_NAMES)
        scene = cls(workspace=ws, width=width, start=start, goal=goal, fixed=fixed, movables=movables,
                    robots=robots, robot_radius=radius)
        validate_scene(scene)
        return scene


# ---------------------------------------------------------------------------------------------------
# Parsing helpers
# ---------------------------------------------------------------------------------------------------

_TOP_KEYS = ("format", "version", "workspace", "vehicle_width", "start", "goal", "fixed", "movables", "robots")
_FIXED_KEYS = ("name", "pieces", "polygon")
_MOVABLE_KEYS = ("name", "pieces", "polygon", "pose", "mass", "inertia", "friction", "shape")


def _read_json_file(path: Path):
    """The JSON document in ``path``; ValueError saying what is wrong with the file itself."""
    text = read_text(path, "a PushAround scene .json file (docs/pusharound.md)")
    try:
        return json.loads(text)
    except json.JSONDecodeError as exc:
        raise ValueError(f"not valid JSON ({exc}).") from None
    except RecursionError:
        raise ValueError("not a scene: its JSON is nested too deeply.") from None


def _kind(v) -> str:
    """What a parsed JSON value is, for messages: ``a string ('abc')``."""
    if v is None:
        return "null"
    kind = {bool: "a boolean", str: "a string", dict: "an object", list: "a list", tuple: "a list"}.get(
        type(v), "a number" if _is_number(v) else type(v).__name__)
    return f"{kind} ({v!r:.40})"


def _is_number(v) -> bool:
    return isinstance(v, numbers.Real) and not isinstance(v, (bool, np.bool_))


def _check_keys(entry: dict, allowed: tuple, field: str, required: tuple = ()) -> None:
    unknown = [k for k in entry if k not in allowed]
    if unknown:
        raise ValueError(f"{field}: unknown key(s) {', '.join(map(repr, unknown))}; the allowed keys are "
                         f"{', '.join(allowed)} (docs/pusharound.md).")
    for key in required:
        if key not in entry:
            raise ValueError(f"{key}: missing; see docs/scene-files.md for the scene format.")


def _list(v, field: str) -> list:
    if not isinstance(v, (list, tuple)):
        raise ValueError(f"{field}: expected a list; got {_kind(v)}.")
    return list(v)


def _name(entry: dict, default: str, field: str) -> str:
    name = entry.get("name", default)
    if not isinstance(name, str):
        raise ValueError(f"{field}.name: expected a string; got {_kind(name)}.")
    return name


def _to_float(v) -> float:
    try:
        return float(v)
    except OverflowError:   # an int beyond float range
        return math.inf if v > 0 else -math.inf


def _scalar(v, field: str) -> float:
    if not _is_number(v):
        raise ValueError(f"{field}: expected a number; got {_kind(v)}.")
    out = _to_float(v)
    if not math.isfinite(out):
        raise ValueError(f"{field}: must be finite; got {v!r}.")
    return out


def _floats(v, n: int, field: str, what: str) -> list:
    if not isinstance(v, (list, tuple, np.ndarray)) or not all(_is_number(x) for x in v):
        raise ValueError(f"{field}: expected {what}; got {_kind(v)}.")
    out = [_to_float(x) for x in v]
    if len(out) != n or not all(math.isfinite(x) for x in out):
        raise ValueError(f"{field}: expected {what} ({n} finite numbers); got {v!r}.")
    if any(abs(x) > MAX_COORDINATE for x in out):
        raise ValueError(f"{field}: values must lie within +-{MAX_COORDINATE:g} m; got {v!r}. Shift the scene's "
                         "origin near the workspace.")
    return out


def _polygon(verts, field: str) -> Polygon:
    if not isinstance(verts, (list, tuple, np.ndarray)):
        raise ValueError(f"{field}: expected a list of [x, y] vertices; got {_kind(verts)}.")
    if len(verts) < 3:
        raise ValueError(f"{field}: expected at least 3 [x, y] vertices; got {len(verts)}.")
    xy = np.asarray([_floats(p, 2, f"{field}[{k}]", "a vertex [x, y]") for k, p in enumerate(verts)],
                    np.float64)
    return shapely.orient_polygons(_valid_polygon(Polygon(xy), field), exterior_cw=False)


def _valid_polygon(poly: Polygon, field: str) -> Polygon:
    """``poly`` if it is a valid polygon of positive area; else ValueError naming ``field``."""
    if not poly.is_valid:
        reason = shapely.is_valid_reason(poly)
        kind = "self-intersecting" if "intersection" in reason.lower() else "invalid"
        raise ValueError(f"{field}: {kind} polygon ({reason}); list the vertices in order around the "
                         "boundary, without crossings or repeated points.")
    if poly.area <= 0:
        raise ValueError(f"{field}: polygon has zero area; give at least 3 non-collinear vertices.")
    return poly


def _check_convex(pieces: tuple, field: str) -> None:
    """ValueError naming ``field[k]`` for the first piece that is not convex."""
    for k, p in enumerate(pieces):
        if not is_convex(p):
            raise ValueError(f"{field}[{k}]: not convex; split it into convex pieces or "
                             "give the outline as 'polygon' to have it decomposed.")


def _check_connected(pieces: tuple, field: str) -> None:
    """ValueError naming ``field`` when the pieces do not form one connected body."""
    if not isinstance(shapely.union_all(pieces), Polygon):
        raise ValueError(f"{field}: they do not form one connected body; pieces must touch "
                         "along edges (or split the body into two obstacles).")


def _pieces(entry: dict, field: str) -> tuple:
    """Convex pieces from ``pieces`` (each must be convex) or ``polygon`` (decomposed if not convex)."""
    if "pieces" in entry and "polygon" in entry:
        raise ValueError(f"{field}: has both 'pieces' and 'polygon'; give one of them.")
    if "pieces" in entry:
        raw = _list(entry["pieces"], f"{field}.pieces")
        pieces = tuple(_polygon(p, f"{field}.pieces[{k}]") for k, p in enumerate(raw))
        if not pieces:
            raise ValueError(f"{field}.pieces: empty; give at least one convex piece.")
        _check_convex(pieces, f"{field}.pieces")
    elif "polygon" in entry:
        pieces = tuple(convex_decomposition(_polygon(entry["polygon"], f"{field}.polygon")))
    else:
        raise ValueError(f"{field}: needs 'pieces' (convex vertex lists) or 'polygon' (an outline).")
    _check_connected(pieces, f"{field}.pieces")
    return pieces


def _parse_fixed(entry, i: int) -> Fixed:
    field = f"fixed[{i}]"
    if not isinstance(entry, dict):
        raise ValueError(f"{field}: expected an object with 'pieces' or 'polygon'; got {_kind(entry)}.")
    _check_keys(entry, _FIXED_KEYS, field)
    return Fixed(name=_name(entry, f"fixed{i}", field), pieces=_pieces(entry, field))


def _parse_movable(entry, i: int) -> Movable:
    field = f"movables[{i}]"
    if not isinstance(entry, dict):
        raise ValueError(f"{field}: expected an object with 'pieces' or 'polygon', 'mass', ...; got "
                         f"{_kind(entry)}.")
    _check_keys(entry, _MOVABLE_KEYS, field)
    name = _name(entry, f"m{i}", field)
    pieces = _pieces(entry, field)
    if "pose" in entry:  # pieces given in the body frame
        x, y, psi = _floats(entry["pose"], 3, f"{field}.pose", "[x, y, psi] (m, m, rad)")
    else:  # pieces given in world coordinates: the body frame is the centroid, psi = 0
        x, y, psi = 0.0, 0.0, 0.0
    # Recentre on the area centroid (the paper's x_m is the centroid), moving the pose to match.
    # A centroid off by float rounding only is left alone, so that save -> load is exact.
    c = shapely.union_all(pieces).centroid
    if math.hypot(c.x, c.y) > 1e-12 * (1.0 + math.sqrt(shapely.union_all(pieces).area)):
        pieces = tuple(affinity.translate(p, -c.x, -c.y) for p in pieces)
        cos, sin = math.cos(psi), math.sin(psi)
        x, y = x + cos * c.x - sin * c.y, y + sin * c.x + cos * c.y
    if "mass" not in entry:
        raise ValueError(f"{field}.mass: missing; give the mass in kg (> 0).")
    mass = _scalar(entry["mass"], f"{field}.mass")
    if mass <= 0:
        raise ValueError(f"{field}.mass: must be > 0 kg; got {mass!r}.")
    inertia = entry.get("inertia")
    if inertia is None:
        inertia = polygon_inertia(shapely.union_all(pieces), mass)
    inertia = _scalar(inertia, f"{field}.inertia")
    if inertia <= 0:
        raise ValueError(f"{field}.inertia: must be > 0 kg m^2 (or omit it to compute it from the "
                         f"polygon and mass); got {inertia!r}.")
    friction = _scalar(entry.get("friction", 0.5), f"{field}.friction")
    if friction < 0:
        raise ValueError(f"{field}.friction: must be >= 0; got {friction!r}.")
    shape = entry.get("shape")
    if shape is not None and not isinstance(shape, dict):
        raise ValueError(f"{field}.shape: expected an object such as {{\"kind\": \"cylinder\", \"radius\": "
                         f"0.3}}, or null; got {_kind(shape)}.")
    return Movable(name=name, pieces=pieces, pose=(x, y, psi), mass=mass,
                   inertia=inertia, friction=friction, shape=dict(shape) if shape else None)


# ---------------------------------------------------------------------------------------------------
# Checks of directly built scenes (the constructors): the file's checks, with TypeError for wrong types
# ---------------------------------------------------------------------------------------------------

# The scene fields check_fields returns, with their names in messages: the constructor's arguments,
# or the keys of a scene file.
_ARG_NAMES = {f: f"PushScene.{f}" for f in ("workspace", "width", "start", "goal", "robots", "robot_radius")}
_FILE_NAMES = {"workspace": "workspace", "width": "vehicle_width", "start": "start", "goal": "goal",
               "robots": "robots.positions", "robot_radius": "robots.radius"}


def _set(obj, field: str, value) -> None:
    """Store a checked (normalised) value on a frozen dataclass."""
    object.__setattr__(obj, field, value)


def _check_name(name, label: str) -> str:
    if not isinstance(name, str):
        raise TypeError(f"{label}.name: expected a string; got {_kind(name)}.")
    return name


def _signed(v, label: str, lo: str, unit: str) -> float:
    """A finite number ``v`` that is ``> 0`` or ``>= 0`` (``lo``); TypeError / ValueError naming ``label``."""
    if not _is_number(v):
        raise TypeError(f"{label}: expected a number{' [' + unit + ']' if unit else ''}; got {_kind(v)}. "
                        f"Pass a float, e.g. {label.rsplit('.', 1)[-1]}=1.0.")
    out = _scalar(v, label)
    if not (out > 0 if lo == "> 0" else out >= 0):
        raise ValueError(f"{label}: must be {lo}{' ' + unit if unit else ''}; got {v!r}.")
    return out


def _numbers(v, n: int, label: str, what: str) -> list:
    """``n`` finite numbers within +-MAX_COORDINATE: TypeError for non-numbers, ValueError otherwise."""
    if isinstance(v, np.ndarray):
        if v.dtype.kind not in "iuf":
            raise TypeError(f"{label}: expected {what}; got an array of dtype {v.dtype}.")
        if v.ndim != 1:
            raise ValueError(f"{label}: expected {what} ({n} numbers); got an array of shape {v.shape}.")
        v = v.tolist()
    if not isinstance(v, (list, tuple)) or not all(_is_number(x) for x in v):
        raise TypeError(f"{label}: expected {what} ({n} numbers); got {_kind(v)}.")
    return _floats(v, n, label, what)


def _robot_array(v, label: str) -> np.ndarray:
    """Robot positions as f64[N, 2] (N >= 0); TypeError for non-numbers, ValueError for shape and values."""
    try:
        arr = np.asarray(v)
    except (ValueError, TypeError):
        raise ValueError(f"{label}: expected an f[N, 2] array of robot positions (x, y) [m]; got ragged rows "
                         f"{v!r:.60}.") from None
    if arr.size == 0:
        return np.zeros((0, 2))
    if arr.dtype.kind not in "iuf":
        raise TypeError(f"{label}: expected numbers, an f[N, 2] array of robot positions (x, y) [m]; got "
                        f"dtype {arr.dtype} ({v!r:.60}).")
    if arr.ndim != 2 or arr.shape[1] != 2:
        raise ValueError(f"{label}: expected shape (N, 2), one (x, y) row [m] a robot; got shape {arr.shape}. "
                         "Pass np.array([[x0, y0], [x1, y1], ...]).")
    arr = arr.astype(np.float64)
    bad = ~np.isfinite(arr).all(axis=1) | (np.abs(arr) > MAX_COORDINATE).any(axis=1)
    if bad.any():
        k = int(np.argmax(bad))
        raise ValueError(f"{label}[{k}]: expected finite (x, y) within +-{MAX_COORDINATE:g} m; got "
                         f"{tuple(arr[k].tolist())}.")
    return arr


def check_fields(workspace, width, start, goal, robots, robot_radius, names: dict = _ARG_NAMES) -> tuple:
    """Check a scene's own fields (types, shapes, finiteness, signs, ranges) and return them normalised:
    (workspace tuple[4], width float, start tuple[2], goal tuple[2], robots f64[N, 2], robot_radius float).

    names: how messages name each field (the constructor's arguments, or a scene file's keys). Raises
    ``TypeError`` for a value of the wrong type, ``ValueError`` for a wrong shape or value.
    """
    ws = tuple(_numbers(workspace, 4, names["workspace"], "[x0, y0, x1, y1] in metres"))
    x0, y0, x1, y1 = ws
    if not (x0 < x1 and y0 < y1):
        raise ValueError(f"{names['workspace']}: need x0 < x1 and y0 < y1; got {ws!r}.")
    if max(x1 - x0, y1 - y0) > MAX_WORKSPACE_SIDE:
        raise ValueError(f"{names['workspace']}: sides of at most {MAX_WORKSPACE_SIDE:g} m; got {x1 - x0:g} x "
                         f"{y1 - y0:g} m. Split the site into workspaces around each corridor.")
    return (ws, _signed(width, names["width"], "> 0", "m"),
            tuple(_numbers(start, 2, names["start"], "[x, y] in metres")),
            tuple(_numbers(goal, 2, names["goal"], "[x, y] in metres")),
            _robot_array(robots, names["robots"]), _signed(robot_radius, names["robot_radius"], "> 0", "m"))


def _check_pieces(pieces, label: str) -> tuple:
    """Convex, valid shapely Polygons with finite coordinates forming one body, as a tuple."""
    if not isinstance(pieces, (list, tuple)):
        raise TypeError(f"{label}: expected a tuple of convex shapely Polygons; got {_kind(pieces)}.")
    if not pieces:
        raise ValueError(f"{label}: empty; give at least one convex piece.")
    for k, p in enumerate(pieces):
        if not isinstance(p, Polygon):
            raise TypeError(f"{label}[{k}]: expected a shapely Polygon (shapely.geometry.Polygon, or the pieces "
                            f"of jaxplan.pusharound.shapes); got {_kind(p)}.")
        xy = shapely.get_coordinates(p)
        if not np.isfinite(xy).all() or np.abs(xy).max() > MAX_COORDINATE:
            raise ValueError(f"{label}[{k}]: coordinates must be finite and within +-{MAX_COORDINATE:g} m; got "
                             f"{p.wkt:.80}.")
        _valid_polygon(p, f"{label}[{k}]")
    pieces = tuple(pieces)
    _check_convex(pieces, label)
    _check_connected(pieces, label)
    return pieces


def _check_parts(parts, kind: type, label: str) -> tuple:
    """``parts`` as a tuple of ``kind`` (Fixed or Movable); TypeError naming ``label[k]`` otherwise."""
    if not isinstance(parts, (list, tuple)):
        raise TypeError(f"{label}: expected a tuple of {kind.__name__}; got {_kind(parts)}.")
    for k, part in enumerate(parts):
        if not isinstance(part, kind):
            raise TypeError(f"{label}[{k}]: expected a {kind.__name__}(...); got {_kind(part)}.")
    return tuple(parts)


# ---------------------------------------------------------------------------------------------------
# Validation
# ---------------------------------------------------------------------------------------------------

def _labels(scene: PushScene) -> list:
    return [f"movables[{i}]" for i in range(len(scene.movables))] + \
           [f"fixed[{i}]" for i in range(len(scene.fixed))]


def validate_scene(scene: PushScene) -> None:
    """Raise ``ValueError`` naming the object for an inconsistent scene: an obstacle outside the
    workspace, two obstacles overlapping, a start, goal or robot inside an obstacle (the fields
    themselves are checked when the scene is built, :func:`check_fields`)."""
    ws = scene.workspace_polygon
    polys = scene.obstacle_polygons()
    labels = _labels(scene)
    for lab, poly in zip(labels, polys):
        if not ws.buffer(1e-9).covers(poly):
            raise ValueError(f"{lab}: lies (partly) outside the workspace {scene.workspace}; move it "
                             "inside or enlarge the workspace.")
    # Pairwise overlap, with a bounding-box pre-filter (STRtree) so large scenes stay fast.
    tree = shapely.STRtree(polys)
    for i, j in zip(*tree.query(polys, predicate="intersects")):
        if i < j:
            area = polys[i].intersection(polys[j]).area
            if area > _OVERLAP_AREA:
                raise ValueError(f"{labels[i]} and {labels[j]}: overlap (area {area:.3g} m^2); move one "
                                 "of them so that they at most touch.")
    for name, pt in (("start", scene.start), ("goal", scene.goal)):
        p = Point(pt)
        if not ws.contains(p):
            raise ValueError(f"{name}: {tuple(pt)} is outside the workspace {scene.workspace}; give a "
                             "point strictly inside it.")
        for lab, poly in zip(labels, polys):
            if poly.covers(p):
                raise ValueError(f"{name}: {tuple(pt)} is inside {lab}; move the {name} or the obstacle.")
    robots = np.asarray(scene.robots, np.float64).reshape(-1, 2)
    for k, pt in enumerate(robots):
        p = Point(pt)
        if not np.all(np.isfinite(pt)) or not ws.contains(p):
            raise ValueError(f"robots.positions[{k}]: {tuple(pt)} is outside the workspace.")
        for lab, poly in zip(labels, polys):
            if poly.distance(p) < scene.robot_radius - 1e-9:
                raise ValueError(f"robots.positions[{k}]: the robot disk overlaps {lab}; move the robot.")
