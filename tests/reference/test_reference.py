"""Sanity tests of the serial reference (jaxplan.reference) against brute force and hand-built cases.

Inputs are built with plain numpy (box, rectangle and circle targets), not jaxplan.transport.scene.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from jaxplan.reference import reference_fabric
from jaxplan.reference.heatmap import highway_mask

# Direction order of docs/transport.md, restated here so the brute force is independent.
DIRS = [(-1, -1), (-1, 0), (-1, 1), (0, -1), (0, 1), (1, -1), (1, 0), (1, 1)]


# ----------------------------------------------------------------------------------------------
# Inputs


def box_inputs(obj, s=1.0):
    """Target = columns >= W-2; d = distance to the edge x = (W-2) s; t = (1, 0)."""
    obj = np.asarray(obj, float)
    h, w = obj.shape
    target = np.zeros((h, w), bool)
    target[:, w - 2:] = True
    x = (np.arange(w) + 0.5) * s
    dist = np.broadcast_to(np.maximum((w - 2) * s - x, 0.0), (h, w)).copy()
    dist[target] = 0.0
    tvec = np.zeros((h, w, 2))
    tvec[~target] = (1.0, 0.0)
    return obj, target, dist, tvec


def _fields_to(closest, x, y, inside):
    """dist / tvec from cell centres (x, y) to their closest target points; 0 inside."""
    dx, dy = closest[0] - x, closest[1] - y
    r = np.hypot(dx, dy)
    safe = np.where(r > 0, r, 1.0)
    dist = np.where(inside, 0.0, r)
    tvec = np.stack([dx / safe, dy / safe], -1)
    tvec[inside] = 0.0
    return dist, tvec


def rect_inputs(obj, s, x0, x1, y0, y1):
    """Axis-aligned rectangle target [x0, x1] x [y0, y1] (world units)."""
    obj = np.asarray(obj, float)
    h, w = obj.shape
    y, x = np.meshgrid((np.arange(h) + 0.5) * s, (np.arange(w) + 0.5) * s, indexing="ij")
    inside = (x >= x0) & (x <= x1) & (y >= y0) & (y <= y1)
    dist, tvec = _fields_to((np.clip(x, x0, x1), np.clip(y, y0, y1)), x, y, inside)
    return obj, inside, dist, tvec


def circle_inputs(obj, s, radius):
    """Disc target of ``radius`` at the grid centre."""
    obj = np.asarray(obj, float)
    h, w = obj.shape
    y, x = np.meshgrid((np.arange(h) + 0.5) * s, (np.arange(w) + 0.5) * s, indexing="ij")
    cx, cy = w * s / 2, h * s / 2
    r = np.hypot(x - cx, y - cy)
    inside = r <= radius
    # Closest point of the circle: the centre direction scaled to the radius.
    safe = np.where(r > 0, r, 1.0)
    px, py = cx + (x - cx) / safe * radius, cy + (y - cy) / safe * radius
    dist, tvec = _fields_to((px, py), x, y, inside)
    return obj, inside, dist, tvec


def random_obj(rng, h, w, p):
    return np.where(rng.random((h, w)) < p, rng.integers(1, 6, (h, w)), 0).astype(float)


# ----------------------------------------------------------------------------------------------
# Brute force: every path by plain recursion


def enumerate_paths(source, vis, is_goal, fallback_len, obj, s, max_hops):
    """Every simple path from ``source`` (plain recursion), sorted best first.

    Entries ``(raw, len, cells, dirs)``; order (raw, -len) with lengths rounded (equal up to float
    noise), then the direction sequence.
    """
    paths = []

    def rec(cells, dirs, raw, length):
        succ = vis(*cells[-1])
        if not succ:
            paths.append((raw, length + fallback_len(cells[-1]), cells, dirs + (8,)))
            return
        if len(dirs) == max_hops:
            return
        for k, n in succ:
            if n in cells:
                continue
            step = s * math.hypot(*DIRS[k])
            if is_goal(n):
                paths.append((raw, length + step, cells + (n,), dirs + (k,)))
            else:
                rec(cells + (n,), dirs + (k,), raw + obj[n], length + step)

    rec((source,), (), obj[source], 0.0)
    paths.sort(key=lambda p: (-p[0], round(p[1] / s, 7), p[3]))
    return paths


def brute_force(obj, target, dist, tvec, s, theta, monotone, max_hops):
    """{source: [(raw, len, cells, dirs), ...] all paths, sorted best first} for every occupied cell."""
    h, w = obj.shape
    occ = ~target & (obj > 0)
    cos_t = math.cos(math.radians(theta))

    def vis(r, c):
        out = []
        for k, (dr, dc) in enumerate(DIRS):
            nr, nc = r + dr, c + dc
            if not (0 <= nr < h and 0 <= nc < w) or not (occ[nr, nc] or target[nr, nc]):
                continue
            n = math.hypot(dr, dc)
            if tvec[r, c, 0] * dc / n + tvec[r, c, 1] * dr / n < cos_t - 1e-6:
                continue
            if monotone and not dist[nr, nc] < dist[r, c] - 1e-5 * s:
                continue
            out.append((k, (nr, nc)))
        return out

    result = {}
    for r in range(h):
        for c in range(w):
            if not occ[r, c]:
                continue
            result[(r, c)] = enumerate_paths((r, c), vis, lambda n: bool(target[n]),
                                             lambda v: dist[v], obj, s, max_hops)
    return result


def assert_matches_brute_force(f, brute, k, s):
    for src, paths in brute.items():
        got = f.candidates[src]
        want = paths[:k]
        assert len(got) == len(want), src
        for (g_raw, g_len, g_cells), (w_raw, w_len, w_cells, _) in zip(got, want):
            assert g_raw == w_raw and g_len == pytest.approx(w_len, abs=1e-9 * s), src
            assert g_cells == list(w_cells), src
        if want:
            assert f.value[src] == want[0][0]
            assert f.length[src] == pytest.approx(want[0][1], abs=1e-9 * s)
            assert f.paths[src] == list(want[0][2])
            for i in range(k):
                expect = want[i][0] if i < len(want) else -math.inf
                assert f.table_raw[src][i] == expect
        else:
            assert f.value[src] == -math.inf and src not in f.paths


SMALL_CASES = [
    # (seed, shape, target builder, theta)
    (0, (4, 4), "box", 60.0),
    (1, (5, 5), "rect", 45.0),
    (2, (5, 5), "rect", 60.0),
    (3, (5, 4), "circle", 75.0),
    (4, (4, 5), "rect", 90.0),
    (5, (5, 5), "circle", 60.0),
    (6, (5, 5), "circle", 45.0),
    (7, (5, 5), "rect", 90.0),
]


def build(kind, obj, s):
    h, w = obj.shape
    if kind == "box":
        return box_inputs(obj, s)
    if kind == "rect":
        return rect_inputs(obj, s, 0.0, 1.2 * s, 0.0, 1.2 * s)   # a corner target: diagonal headings
    return circle_inputs(obj, s, 0.9 * s)


@pytest.mark.parametrize("seed,shape,kind,theta", SMALL_CASES)
@pytest.mark.parametrize("monotone,reuse", [(True, True), (True, False), (False, False)])
def test_astar_matches_brute_force(seed, shape, kind, theta, monotone, reuse):
    # reuse=False matters: with reuse every successor of a source is already solved, so the search
    # never goes deeper than one step and its pruning is not exercised.
    rng = np.random.default_rng(seed)
    s = 0.5
    obj, target, dist, tvec = build(kind, random_obj(rng, *shape, p=0.75), s)
    k = 4
    max_hops = shape[0] * shape[1] if monotone else 2 * (shape[0] + shape[1])
    f = reference_fabric(obj, target, dist, tvec, s, theta, monotone=monotone, k=k, reuse=reuse,
                         with_connectors=False)
    brute = brute_force(obj, target, dist, tvec, s, theta, monotone, max_hops)
    assert set(brute) == set(f.candidates)
    assert_matches_brute_force(f, brute, k, s)


@pytest.mark.parametrize("seed", [100, 101, 102, 103])
@pytest.mark.parametrize("k", [1, 2, 4])
def test_pruning_matches_brute_force_on_dense_grids(seed, k):
    """Dense 6x6 grids without reuse: many prefixes meet at each node, so the per-node K-dominance
    pruning (and the exact prefix-length order it relies on) decides what survives."""
    s = 0.5
    for kind in ("rect", "circle"):
        for theta in (45.0, 60.0, 90.0):
            obj, target, dist, tvec = build(kind, random_obj(np.random.default_rng(seed), 6, 6, 0.9), s)
            f = reference_fabric(obj, target, dist, tvec, s, theta, k=k, reuse=False, with_connectors=False)
            brute = brute_force(obj, target, dist, tvec, s, theta, True, 36)
            assert_matches_brute_force(f, brute, k, s)


@pytest.mark.parametrize("monotone,max_hops", [(True, 2), (True, 3), (False, 3)])
def test_hop_cap_matches_brute_force(monotone, max_hops):
    """A binding hop cap: the search switches to (node, hops) pruning and drops reuse."""
    rng = np.random.default_rng(7)
    s = 1.0
    obj, target, dist, tvec = rect_inputs(random_obj(rng, 5, 5, 0.8), s, 0.0, 1.2, 0.0, 1.2)
    f = reference_fabric(obj, target, dist, tvec, s, 70.0, monotone=monotone, k=3, max_hops=max_hops,
                         with_connectors=False)
    brute = brute_force(obj, target, dist, tvec, s, 70.0, monotone, max_hops)
    assert_matches_brute_force(f, brute, 3, s)


def test_non_monotone_cycles_use_simple_paths():
    """theta = 90 on a box target: vertical steps are cone-feasible both ways (cycles)."""
    obj, target, dist, tvec = box_inputs(np.array([[1, 2, 0, 0], [3, 1, 0, 0], [2, 2, 0, 0]]), 1.0)
    f = reference_fabric(obj, target, dist, tvec, 1.0, 90.0, monotone=False, k=4, with_connectors=False)
    brute = brute_force(obj, target, dist, tvec, 1.0, 90.0, False, 2 * (3 + 4))
    assert_matches_brute_force(f, brute, 4, 1.0)
    # (0, 1) can climb the whole column 1 before entering the target: 2 + 1 + 2 = 5.
    assert f.value[0, 1] == 5.0


def brute_force_connector(obj, occupied, root, anchor, s, theta, monotone, max_hops):
    """Best (raw, len, cells) over every connector root -> anchor, by plain recursion."""
    h, w = obj.shape
    cos_t = math.cos(math.radians(theta))

    def to_anchor(cell):
        return s * math.hypot(anchor[0] - cell[0], anchor[1] - cell[1])

    def vis(r, c):
        out = []
        fx, fy = anchor[1] - c, anchor[0] - r
        fn = math.hypot(fx, fy)
        for k, (dr, dc) in enumerate(DIRS):
            n = (r + dr, c + dc)
            if not (0 <= n[0] < h and 0 <= n[1] < w) or not (occupied[n] or n == anchor):
                continue
            if (fx * dc + fy * dr) / (fn * math.hypot(dr, dc)) < cos_t - 1e-6:
                continue
            if monotone and not to_anchor(n) < to_anchor((r, c)) - 1e-5 * s:
                continue
            out.append((k, n))
        return out

    found = enumerate_paths(root, vis, lambda n: n == anchor, to_anchor, obj, s, max_hops)
    return found[0] if found else None


@pytest.mark.parametrize("monotone,shape,seed", [(True, (7, 7), 11), (True, (6, 8), 12), (False, (5, 5), 13)])
def test_anchors_and_connectors_match_brute_force(monotone, shape, seed):
    rng = np.random.default_rng(seed)
    s = 0.5
    obj, target, dist, tvec = circle_inputs(random_obj(rng, *shape, p=0.7), s, 1.1 * s)
    f = reference_fabric(obj, target, dist, tvec, s, 60.0, monotone=monotone, tau_h=0.3, anchor_lambda=0.5)
    roots = f.occupied & ~f.highways
    cand = np.argwhere(f.highways & f.occupied)            # row-major order
    assert roots.any() and len(cand) > 0
    max_hops = shape[0] * shape[1] if monotone else 2 * (shape[0] + shape[1])
    for r, c in np.argwhere(roots):
        # Eq. 12 vectorised; np.argmax takes the first (lowest row-major) of equal maxima.
        score = f.heat[cand[:, 0], cand[:, 1]] - 0.5 * s * np.hypot(cand[:, 0] - r, cand[:, 1] - c)
        hstar = tuple(int(v) for v in cand[np.argmax(score)])
        assert tuple(f.anchor[r, c]) == hstar
        best = brute_force_connector(obj, f.occupied, (r, c), hstar, s, 60.0, monotone, max_hops)
        assert f.conn_raw[r, c] == best[0]
        assert f.conn_len[r, c] == pytest.approx(best[1], abs=1e-9 * s)
        assert f.conn_paths[(r, c)] == list(best[2])
        assert f.via_raw[r, c] == best[0] + f.value[hstar]
        assert f.via_len[r, c] == pytest.approx(best[1] + f.length[hstar])
        if len(best[2]) > 1:
            assert tuple(f.conn_first_hop[r, c]) == best[2][1]
    assert (f.anchor[~roots] == -1).all()


# ----------------------------------------------------------------------------------------------
# Continuation reuse


FIELDS = ("value", "length", "first_hop", "heading", "fallback", "table_raw", "table_len", "psi",
          "heat", "highways", "unique_first_hop", "anchor", "conn_raw", "conn_len", "via_raw", "via_len")


@pytest.mark.parametrize("n,p,theta", [(12, 0.5, 60.0), (20, 0.9, 60.0), (20, 0.9, 90.0)])
def test_reuse_gives_same_outputs_and_fewer_expansions(n, p, theta):
    rng = np.random.default_rng(n)
    s = 0.5
    obj, target, dist, tvec = circle_inputs(random_obj(rng, n, n, p), s, 0.2 * n * s)
    on = reference_fabric(obj, target, dist, tvec, s, theta, reuse=True)
    off = reference_fabric(obj, target, dist, tvec, s, theta, reuse=False)
    for name in FIELDS:
        np.testing.assert_array_equal(getattr(on, name), getattr(off, name), err_msg=name)
    assert on.paths == off.paths and on.candidates == off.candidates
    assert on.stats["expansions"] <= off.stats["expansions"]
    assert on.stats["substitutions"] > 0 and off.stats["substitutions"] == 0


# ----------------------------------------------------------------------------------------------
# Hand-built cases


def test_straight_row_chain():
    """Row 1 of a 3-row grid: cells with 2, 3, 4 objects, then a box target (columns 4, 5)."""
    s = 2.0
    grid = np.zeros((3, 6))
    grid[1, 1:4] = [2, 3, 4]
    obj, target, dist, tvec = box_inputs(grid, s)
    # theta = 30 keeps diagonal steps (45 degrees off t) out: one path per source.
    f = reference_fabric(obj, target, dist, tvec, s, 30.0, k=4, tau_h=0.5, anchor_lambda=1.0)
    np.testing.assert_array_equal(f.value[1], [0, 9, 7, 4, 0, 0])
    np.testing.assert_allclose(f.length[1], [0, 3 * s, 2 * s, s, 0, 0])
    assert f.paths[(1, 1)] == [(1, 1), (1, 2), (1, 3), (1, 4)]
    for c in (1, 2, 3):
        assert tuple(f.first_hop[1, c]) == (1, c + 1)
        assert tuple(f.heading[1, c]) == (1.0, 0.0)
        assert f.unique_first_hop[1, c]
    assert not f.fallback.any()
    assert (f.first_hop[0] == -1).all() and (f.first_hop[2] == -1).all()
    # One path per source: unused table entries are -inf / +inf.
    assert f.table_raw[1, 1, 0] == 9 and np.isneginf(f.table_raw[1, 1, 1:]).all()
    assert np.isposinf(f.table_len[1, 1, 1:]).all()
    # psi: every path carries J of its source; the longest one (9) covers the chain and (1, 4).
    expected_psi = np.zeros((3, 6))
    expected_psi[1, 1:5] = 9
    np.testing.assert_array_equal(f.psi, expected_psi)
    # heat: X = (1, 2) and (1, 3) each have a source one step behind, aligned (a = 1), psi 9.
    # Off-row cells are a diagonal away (|x - c| = s sqrt 2 > |c1 - c| = s): gated out.
    expected_heat = np.zeros((3, 6))
    expected_heat[1, 2:4] = 9
    np.testing.assert_array_equal(f.heat, expected_heat)
    np.testing.assert_array_equal(f.highways, expected_heat > 0)
    # Root (1, 1): anchors (1, 2) (9 - 1*s) beats (1, 3) (9 - 2*s); connector = one step.
    assert tuple(f.anchor[1, 1]) == (1, 2)
    assert (f.anchor[1, 2:] == -1).all()
    assert f.conn_raw[1, 1] == 2 and f.conn_len[1, 1] == pytest.approx(s)
    assert tuple(f.conn_first_hop[1, 1]) == (1, 2)
    assert f.via_raw[1, 1] == 9 and f.via_len[1, 1] == pytest.approx(3 * s)


def test_fallback_cell():
    """(0, 0) has no occupied neighbour toward the target: boundary fallback."""
    s = 1.0
    obj, target, dist, tvec = box_inputs(np.array([[1, 0, 3, 0, 0]]), s)
    f = reference_fabric(obj, target, dist, tvec, s, 60.0)
    assert f.fallback[0, 0] and not f.fallback[0, 2]
    assert f.value[0, 0] == 1 and f.length[0, 0] == pytest.approx(2.5 * s)   # d = (3 - 0.5) s
    assert f.paths[(0, 0)] == [(0, 0)]
    assert tuple(f.first_hop[0, 0]) == (0, 1)            # best aligned with t = (1, 0)
    assert not f.feasible[0, 0].any()
    assert f.value[0, 2] == 3 and f.length[0, 2] == pytest.approx(s)
    # The fallback hop feeds the heatmap: X = (0, 1) sees source (0, 0) straight ahead, psi = 1.
    np.testing.assert_array_equal(f.heat[0], [0, 1, 0, 0, 0])


def test_exact_tie_goes_to_lower_direction():
    """(1, 1) reaches the target by (-1, 1) (index 2) or (1, 1) (index 7): equal raw and length."""
    s = 1.0
    grid = np.zeros((3, 5))
    grid[1, 1] = grid[0, 2] = grid[2, 2] = 1
    obj, target, dist, tvec = box_inputs(grid, s)
    f = reference_fabric(obj, target, dist, tvec, s, 45.0)
    assert f.feasible[1, 1, 2] and f.feasible[1, 1, 7]     # exact 45-degree cone boundary
    assert tuple(f.first_hop[1, 1]) == (0, 2)
    # All four paths collect 2; s(1 + sqrt 2) beats 2 s sqrt 2; ties in direction order.
    assert [c for _, _, c in f.candidates[(1, 1)]] == [
        [(1, 1), (0, 2), (0, 3)], [(1, 1), (2, 2), (2, 3)],     # dirs (2, 4), (7, 4)
        [(1, 1), (0, 2), (1, 3)], [(1, 1), (2, 2), (1, 3)],     # dirs (2, 7), (7, 2)
    ]
    np.testing.assert_allclose(f.table_len[1, 1], [1 + math.sqrt(2)] * 2 + [2 * math.sqrt(2)] * 2)
    assert not f.unique_first_hop[1, 1]


def test_slack_candidates_and_one_by_one_grid():
    rng = np.random.default_rng(3)
    obj, target, dist, tvec = circle_inputs(random_obj(rng, 9, 9, 0.7), 1.0, 1.5)
    full = reference_fabric(obj, target, dist, tvec, 1.0, 60.0, with_connectors=False)
    slack = reference_fabric(obj, target, dist, tvec, 1.0, 60.0, slack_tau=1.0, with_connectors=False)
    np.testing.assert_array_equal(full.table_raw, slack.table_raw)
    for src, cands in full.candidates.items():
        assert slack.candidates[src] == [x for x in cands if x[0] >= full.value[src] - 1.0]
    # A 1x1 grid: the cell falls back and has no neighbour, so no first hop.
    one = reference_fabric(np.ones((1, 1)), np.zeros((1, 1), bool), np.ones((1, 1)),
                           np.array([[[1.0, 0.0]]]), 1.0, 60.0)
    assert one.fallback[0, 0] and one.value[0, 0] == 1 and one.length[0, 0] == 1
    assert (one.first_hop == -1).all() and (one.heading == 0).all()


def test_highway_smoothing_and_nms():
    heat = np.ones((3, 3))
    heat[1, 1] = 2.0
    none = np.zeros((3, 3), bool)
    # Smoothed: corners (1+1+1+2)/4 = 1.25, edges 7/6, centre 10/9. tau = 1 (relative): corners only.
    corners = np.zeros((3, 3), bool)
    corners[::2, ::2] = True
    np.testing.assert_array_equal(highway_mask(heat, none, 1.0, smoothing=True), corners)
    # Non-max suppression on the smoothed map: only the centre is below its neighbours on every axis.
    not_centre = np.ones((3, 3), bool)
    not_centre[1, 1] = False
    np.testing.assert_array_equal(highway_mask(heat, none, 0.0, smoothing=True, nms=True), not_centre)
    # Absolute threshold, no smoothing; target cells are never highways.
    target = np.zeros((3, 3), bool)
    target[1, 1] = True
    expected = np.zeros((3, 3), bool)
    np.testing.assert_array_equal(highway_mask(heat, target, 1.5, relative=False), expected)
    np.testing.assert_array_equal(highway_mask(heat, target, 1.0, relative=False), ~target)


def test_a_fallback_hop_at_a_direction_tie_is_not_unique():
    """t(C) at 157.5 degrees aligns equally with the 135 and 180 degree steps: float32 and float64 may
    break that tie differently, so the reference must not call such a first hop unique (a hypothesis
    example once failed the psi/heat equality on it)."""
    from jaxplan.reference.fabric import _fallback_tied

    tie = (math.cos(math.radians(157.5)), math.sin(math.radians(157.5)))
    clear = (math.cos(math.radians(170.0)), math.sin(math.radians(170.0)))
    assert _fallback_tied(3, 3, tie, (7, 7))
    assert not _fallback_tied(3, 3, clear, (7, 7))
    assert not _fallback_tied(0, 3, (1.0, 0.0), (1, 7)) and not _fallback_tied(0, 0, tie, (1, 1))
