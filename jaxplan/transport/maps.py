"""Sites from real maps: the MovingAI grid benchmarks' ``.map`` files as blocked cells, and a scene on them.

A MovingAI ``.map`` file (https://movingai.com/benchmarks/, "Map format") is four header lines and a
grid of characters::

    type octile
    height 4
    width 6
    map
    ......
    .@@@T.
    .@@@..
    ......

:func:`read_movingai_map` reads it into ``blocked: bool[H, W]``: ``@``, ``O`` (out of bounds), ``T``
(trees) and ``W`` (water) are blocked, ``.``, ``G`` (ground) and ``S`` (swamp) are free. The rows are
flipped into the Scene's convention (rows = y, row 0 at the grid's lower edge): row ``r`` of the result
is the ``(H - r)``-th grid line of the file, so the file's last line is row 0 and a plot with
``origin='lower'`` shows the map as the file draws it. A MovingAI ``(x, y)`` (y counted down from the
top line) is cell ``(row H - 1 - y, col x)``.

:func:`site_from_map` puts a transport job on the map: targets and gaussian piles of material on free
cells, drawn from a seed. The formats and the checks are in ``docs/scene-files.md``.
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
from shapely.geometry import MultiPolygon

from jaxplan.transport.scene import Scene, box, circle
from jaxplan.transport.scene_files import MAX_FILE_SIDE

__all__ = ["BLOCKED_MAP_CHARS", "FREE_MAP_CHARS", "MAX_PILE_COUNT", "read_movingai_map", "site_from_map"]

BLOCKED_MAP_CHARS = "@OTW"
"""MovingAI map characters of blocked cells: out of bounds (``@``, ``O``), trees (``T``), water (``W``)."""
FREE_MAP_CHARS = ".GS"
"""MovingAI map characters of free cells: passable terrain (``.``, ``G``), swamp (``S``)."""
MAX_PILE_COUNT = 6
"""Most objects one cell of a :func:`site_from_map` site holds (as ``random_scene``'s ``max_count``)."""

_FREE, _BLOCKED, _BAD = 0, 1, 2
_CLASS = np.full(256, _BAD, np.uint8)
_CLASS[[ord(ch) for ch in FREE_MAP_CHARS]] = _FREE
_CLASS[[ord(ch) for ch in BLOCKED_MAP_CHARS]] = _BLOCKED

_HEADER_LINES = 4
_MAX_HEADER_BYTES = 4096
# a map of MAX_FILE_SIDE x MAX_FILE_SIDE cells with CRLF line ends, its header and some blank lines
_MAX_MAP_BYTES = _MAX_HEADER_BYTES + MAX_FILE_SIDE * (MAX_FILE_SIDE + 2) + 4096
_CHARS_TEXT = (f"a MovingAI map cell is {', '.join(map(repr, FREE_MAP_CHARS))} (free) or "
               f"{', '.join(map(repr, BLOCKED_MAP_CHARS))} (blocked)")

# gaussian piles, as the fleet sites' (jaxplan.fleet): one pile per this many free cells by default,
# sigma in cells, evaluated within this many sigmas of the centre
_CELLS_PER_PILE = 512
_SIGMA = (1.2, 3.0)
_PILE_REACH = 6.0


class _MapProblem(ValueError):
    """What is wrong with a map file, as ``"<what>; <fix>"``; :func:`read_movingai_map` adds the path."""


# --------------------------------------------------------------------------------------------------
# Reading
# --------------------------------------------------------------------------------------------------

def _shown(line: str, limit: int = 40) -> str:
    return repr(line if len(line) <= limit else line[:limit] + "...")


def _header_size(line: str, number: int, key: str) -> int:
    words = line.split()
    if len(words) != 2 or words[0] != key:
        raise _MapProblem(f"line {number}: expected '{key} N' (the MovingAI header is 'type octile', "
                          f"'height H', 'width W', 'map'); got {_shown(line)}")
    try:
        value = int(words[1])
    except ValueError:
        value = None
    if value is None or not 1 <= value <= MAX_FILE_SIDE:
        raise _MapProblem(f"line {number}: {key} must be an integer in [1, {MAX_FILE_SIDE}] (a map holds at most "
                          f"{MAX_FILE_SIDE} x {MAX_FILE_SIDE} cells, as a scene file); got {words[1]!r}")
    return value


def _parse_header(lines) -> tuple[int, int]:
    if len(lines) < _HEADER_LINES:
        raise _MapProblem(f"has {len(lines)} line(s), fewer than the {_HEADER_LINES} header lines ('type octile', "
                          "'height H', 'width W', 'map'); see https://movingai.com/benchmarks/formats.html")
    if lines[0].split() != ["type", "octile"]:
        raise _MapProblem(f"line 1: expected 'type octile', the first line of a MovingAI map; got {_shown(lines[0])}")
    first = lines[1].split()[:1]
    order = ("width", "height") if first == ["width"] else ("height", "width")   # height first, as published
    sizes = {key: _header_size(lines[1 + i], 2 + i, key) for i, key in enumerate(order)}
    if lines[3].strip() != "map":
        raise _MapProblem(f"line 4: expected 'map', which ends the header; got {_shown(lines[3])}")
    return sizes["height"], sizes["width"]


def _parse_grid(lines, height: int, width: int) -> np.ndarray:
    """``bool[H, W]`` in the file's order (row 0 = the first grid line)."""
    rows = lines[_HEADER_LINES:_HEADER_LINES + height]
    if len(rows) < height:
        raise _MapProblem(f"has {len(rows)} grid line(s) after 'map' but the header says height {height}; "
                          "add the missing lines or correct the height")
    for i, row in enumerate(rows):
        if len(row) != width:
            raise _MapProblem(f"line {_HEADER_LINES + 1 + i}: has {len(row)} character(s) but the header says "
                              f"width {width}; every grid line holds exactly W characters")
    extra = next((i for i, line in enumerate(lines[_HEADER_LINES + height:]) if line.strip()), None)
    if extra is not None:
        raise _MapProblem(f"line {_HEADER_LINES + height + 1 + extra}: more grid lines than the header's height "
                          f"{height}; remove them or correct the height")
    codes = _CLASS[np.frombuffer("".join(rows).encode("latin-1"), np.uint8)].reshape(height, width)
    bad = codes == _BAD
    if bad.any():
        r, c = (int(v) for v in np.argwhere(bad)[0])
        ch = rows[r][c]
        shown = repr(ch) if " " <= ch <= "~" else f"the byte 0x{ord(ch):02x}"
        raise _MapProblem(f"line {_HEADER_LINES + 1 + r}, character {c + 1}: {shown} is not a map character; "
                          f"{_CHARS_TEXT}")
    return codes == _BLOCKED


def _read_map(path: Path) -> np.ndarray:
    if path.is_dir():
        raise _MapProblem("is a directory; give the path of a MovingAI .map file")
    size = path.stat().st_size
    if size == 0:
        raise _MapProblem("is empty (0 bytes); a MovingAI .map file starts with 'type octile'")
    if size > _MAX_MAP_BYTES:
        raise _MapProblem(f"is {size:,} bytes, more than a map of {MAX_FILE_SIDE} x {MAX_FILE_SIDE} cells takes "
                          f"({_MAX_MAP_BYTES:,}); a map holds at most {MAX_FILE_SIDE} x {MAX_FILE_SIDE} cells")
    text = path.read_bytes().decode("latin-1")   # every byte is a character: a stray byte is named, not a decoder error
    lines = [line[:-1] if line.endswith("\r") else line for line in text.split("\n")]
    while len(lines) > _HEADER_LINES and not lines[-1].strip():   # blank lines at the end (a grid line is never empty)
        lines.pop()
    height, width = _parse_header(lines)
    return _parse_grid(lines, height, width)


def read_movingai_map(path) -> np.ndarray:
    """The blocked cells of the MovingAI ``.map`` file at ``path``: ``bool[H, W]``, rows = y.

    ``@ O T W`` are blocked, ``. G S`` free. Row ``r`` is the file's ``(H - r)``-th grid line (the file's
    top line is row ``H - 1``): the Scene's convention, so ``Scene.from_arrays(obj, target,
    blocked=read_movingai_map(path))`` plotted with ``origin='lower'`` looks as the file does.

    Every problem with the file raises one ``ValueError("Map file <path>: <what>; <fix>")``, naming the line
    (and character) at fault: a missing or directory path, an unreadable or empty file, a header other than
    ``type octile`` / ``height H`` / ``width W`` / ``map`` (H and W in ``[1, MAX_FILE_SIDE]``), too few or
    too many grid lines, a line of the wrong length, a character outside the seven above.
    """
    path = Path(path)
    try:
        blocked = _read_map(path)
    except _MapProblem as exc:
        raise ValueError(f"Map file {path}: {exc}.") from None
    except FileNotFoundError:
        raise ValueError(f"Map file {path}: no such file; check the path.") from None
    except OSError as exc:   # permissions, a device error, ...
        raise ValueError(f"Map file {path}: could not be read ({exc.strerror or exc}); check the file's "
                         "permissions.") from None
    return np.ascontiguousarray(blocked[::-1])


# --------------------------------------------------------------------------------------------------
# Sites
# --------------------------------------------------------------------------------------------------

def _check_int(value, what: str, lo: int, hi: int | None = None) -> int:
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)) or value < lo or \
            (hi is not None and value > hi):
        span = f"an int >= {lo}" if hi is None else f"an int in [{lo}, {hi}]"
        raise ValueError(f"site_from_map: {what}: must be {span}; got {value!r}.")
    return int(value)


def _check_number(value, what: str, *, positive: bool) -> float:
    try:
        x = float(value)
    except (TypeError, ValueError):
        x = math.nan
    if isinstance(value, (bool, np.bool_)) or not math.isfinite(x) or (x <= 0 if positive else x < 0):
        raise ValueError(f"site_from_map: {what}: must be a finite number {'> 0' if positive else '>= 0'}; "
                         f"got {value!r}.")
    return x


def _window_sums(mask: np.ndarray, k: int) -> np.ndarray:
    """``i64[H, W]``: cells of ``mask`` in the ``(2k+1)``-square centred on each cell; a square that leaves
    the grid counts as full (it is never free)."""
    h, w = mask.shape
    side = 2 * k + 1
    sums = np.full((h, w), side * side, np.int64)
    if side > h or side > w:
        return sums
    integral = np.zeros((h + 1, w + 1), np.int64)
    integral[1:, 1:] = mask.astype(np.int64).cumsum(0).cumsum(1)
    inner = integral[side:, side:] - integral[:-side, side:] - integral[side:, :-side] + integral[:-side, :-side]
    sums[k:h - k, k:w - k] = inner
    return sums


def _largest_component(free: np.ndarray) -> np.ndarray:
    """``bool[H, W]``: the largest 4-connected set of ``free`` cells (ties: the one reached first in row-major
    order). A rover's open steps (no corner cutting) connect exactly the 4-connected cells. Union-find over
    each row's runs of free cells, so the cost grows with the runs, not the cells."""
    h, w = free.shape
    padded = np.zeros((h, w + 2), np.int8)
    padded[:, 1:-1] = free
    edges = np.diff(padded, axis=1)
    rows = []   # per row: (starts, ends, first run index)
    count = 0
    for r in range(h):
        starts, ends = np.flatnonzero(edges[r] == 1), np.flatnonzero(edges[r] == -1)
        rows.append((starts, ends, count))
        count += starts.size
    if count == 0:
        return np.zeros((h, w), bool)
    parent = list(range(count))

    def root(i: int) -> int:
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    for r in range(1, h):
        (s0, e0, base0), (s1, e1, base1) = rows[r - 1], rows[r]
        i = j = 0
        while i < s0.size and j < s1.size:   # runs [s, e) of two rows touch when their columns overlap
            if s0[i] < e1[j] and s1[j] < e0[i]:
                a, b = root(base0 + i), root(base1 + j)
                if a != b:
                    parent[max(a, b)] = min(a, b)
            if e0[i] <= e1[j]:
                i += 1
            else:
                j += 1
    lengths = np.concatenate([e - s for s, e, _ in rows])
    roots = np.array([root(i) for i in range(count)])
    sizes = np.bincount(roots, weights=lengths, minlength=count)
    keep = roots == int(np.argmax(sizes))
    out = np.zeros((h, w), bool)
    for r, (starts, ends, base) in enumerate(rows):
        for i in np.flatnonzero(keep[base:base + starts.size]):
            out[r, starts[i]:ends[i]] = True
    return out


def _place_target(rng, taken: np.ndarray, region: np.ndarray, radius: float, flexible: bool, cell_size: float):
    """One target (a circle of ``radius`` cells, or a box within the same square) on a ``(2k+1)``-square of
    cells none of which is ``taken``, centred in ``region``, ``k = floor(radius)``; with ``flexible``, the
    largest ``k <= floor(radius)`` that fits. Returns ``(polygon, (r0, r1, c0, c1) of the square)`` or None
    when nothing fits."""
    k = int(math.floor(radius))
    while k >= 0:
        free = np.flatnonzero((_window_sums(taken, k) == 0) & region)
        if free.size:
            break
        if not flexible:
            return None
        k -= 1
    else:
        return None
    r, c = divmod(int(rng.choice(free)), taken.shape[1])
    if rng.random() < 0.5:   # a circle: it covers the centres within ``rad`` cells, all in the square
        rad = radius if k == int(math.floor(radius)) else k + 0.75
        shape = circle(((c + 0.5) * cell_size, (r + 0.5) * cell_size), rad * cell_size)
    else:                    # a box of whole cells within the square: its edges lie between cell centres
        ky, kx = (int(rng.integers((k + 1) // 2, k + 1)) for _ in range(2))
        shape = box((c - kx) * cell_size, (r - ky) * cell_size, (c + kx + 1) * cell_size, (r + ky + 1) * cell_size)
    return shape, (r - k, r + k + 1, c - k, c + k + 1)


def _pile_counts(rng, free: np.ndarray, n_piles: int, fill: float) -> np.ndarray:
    """``f64[H, W]`` integer counts (0..MAX_PILE_COUNT) on the ``free`` cells only: ``n_piles`` gaussian
    piles centred on free cells (sigma in [1.2, 3] cells, relative heights in [0.5, 1]), scaled so that
    the free cells hold ``fill`` objects each on average before rounding and the cap."""
    h, w = free.shape
    obj = np.zeros((h, w))
    cells = np.flatnonzero(free)
    if n_piles == 0 or fill == 0 or cells.size == 0:
        return obj
    centres = rng.choice(cells, n_piles)
    sigma = rng.uniform(*_SIGMA, n_piles)
    height = rng.uniform(0.5, 1.0, n_piles)
    for flat, s, a in zip(centres, sigma, height):
        r, c = divmod(int(flat), w)
        reach = int(math.ceil(_PILE_REACH * s))
        r0, r1, c0, c1 = max(0, r - reach), min(h, r + reach + 1), max(0, c - reach), min(w, c + reach + 1)
        ys, xs = np.mgrid[r0:r1, c0:c1]
        obj[r0:r1, c0:c1] += a * np.exp(-((xs - c) ** 2 + (ys - r) ** 2) / (2.0 * s * s))
    obj = np.where(free, obj, 0.0)
    obj *= fill * cells.size / obj.sum()
    return np.clip(np.rint(obj), 0, MAX_PILE_COUNT)


def site_from_map(path, seed: int = 0, *, n_targets: int = 2, target_radius=None, n_piles=None,
                  fill: float = 0.25, cell_size: float = 1.0, name=None) -> Scene:
    """A transport scene on the MovingAI ``.map`` at ``path``: its blocked cells, targets and material
    piles on its free cells, the same for the same arguments on every machine.

    blocked: :func:`read_movingai_map` (rows flipped: the file's top line is the grid's top row).
    targets: ``n_targets`` polygons, each a circle of ``target_radius`` cells or a box of whole cells
      inside the same ``(2k+1)``-square, ``k = floor(target_radius)``, drawn (uniformly among the places
      that fit) in the map's largest 4-connected area of free cells, where every cell of the square is
      free and at least one free cell from every other target's square: no target covers a blocked
      cell's centre, and targets do not touch. Default
      radius: ``max(1.5, 0.03 min(H, W))`` cells, reduced to the largest square that fits where the map
      has no room for it; a given ``target_radius`` that does not fit raises ValueError.
    material: ``n_piles`` gaussian piles (default one per 512 free cells, at least 1) centred on free
      cells anywhere on the map, counts on free cells outside the targets only, scaled to about ``fill``
      objects per such cell (before rounding to integers and the cap of ``MAX_PILE_COUNT`` per cell).
      Piles are not kept to the targets' side of walls: material on cells that no target can be reached
      from stays in the scene, is never planned and is reported by ``Scene.unreachable_mass``
      (``Scene.cut_off`` marks those cells).
    seed: an int >= 0 for ``numpy.random.default_rng``; cell_size: world units per cell (origin (0, 0));
    name: default ``"<map file stem>_site<seed>"``.

    Raises ValueError naming the file (``"Map file <path>: ..."``) or the argument
    (``"site_from_map: <argument>: ..."``).
    """
    seed = _check_int(seed, "seed", 0)
    n_targets = _check_int(n_targets, "n_targets", 1, 64)
    fill = _check_number(fill, "fill", positive=False)
    cell_size = _check_number(cell_size, "cell_size", positive=True)
    if target_radius is not None:
        target_radius = _check_number(target_radius, "target_radius (cells)", positive=True)
    if n_piles is not None:
        n_piles = _check_int(n_piles, "n_piles", 0, 1_000_000)
    if name is not None and not isinstance(name, str):
        raise ValueError(f"site_from_map: name: must be a str or None; got {type(name).__name__}.")
    path = Path(path)
    blocked = read_movingai_map(path)
    h, w = blocked.shape
    rng = np.random.default_rng(seed)

    radius = target_radius if target_radius is not None else max(1.5, 0.03 * min(h, w))
    if blocked.all():
        raise ValueError(f"Map file {path}: every cell is blocked; a site needs free cells for its targets.")
    region = _largest_component(~blocked)
    taken = blocked.copy()
    targets = []
    for i in range(n_targets):
        placed = _place_target(rng, taken, region, radius, target_radius is None, cell_size)
        if placed is None:
            what = (f"a square of {2 * int(radius) + 1} x {2 * int(radius) + 1} free cells for target {i + 1} "
                    f"of {n_targets} (target_radius {radius:g} cells)" if target_radius is not None
                    else f"a free cell for target {i + 1} of {n_targets}")
            raise ValueError(f"Map file {path}: has no room for {what} in the map's largest connected free area, "
                             "away from blocked cells and the other targets; use a smaller target_radius or fewer "
                             "n_targets.")
        shape, (r0, r1, c0, c1) = placed
        targets.append(shape)
        taken[max(0, r0 - 1):r1 + 1, max(0, c0 - 1):c1 + 1] = True   # one free cell between targets
    target = targets[0] if len(targets) == 1 else MultiPolygon(targets)

    name = name if name is not None else f"{path.stem}_site{seed}"
    scene = Scene.from_arrays(np.zeros((h, w)), target, cell_size=cell_size, name=name, blocked=blocked)
    free = ~blocked & ~np.asarray(scene.target_mask)
    if n_piles is None:
        n_piles = max(1, int(free.sum()) // _CELLS_PER_PILE)
    return scene.with_obj(_pile_counts(rng, free, n_piles, fill))
