"""Batched convex-polygon geometry as JAX array kernels.

Convex polygons are packed into ``verts: f[N, V, 2]`` (counter-clockwise, padded by repeating the
last vertex, so padding adds zero-length edges and changes nothing) and ``nverts: i32[N]``.

- :func:`aabb_gaps`: the quick pass, a lower bound on every pair's distance from bounding boxes.
- :func:`pair_distances`: exact distance and closest points of many polygon pairs at once (the
  vertex-edge minimum, with a separating test for overlap), ``vmap`` over pairs.
- :func:`point_distances`: distance from points to polygons (0 inside), for endpoint clearance.

Why JAX and not shapely: the WCCG needs every pair within range, and the later hybrid search needs the
same quantities for a batch of candidate poses coming out of vmapped rollouts, inside ``jit``. The
kernels are dtype-agnostic; :func:`jaxplan.pusharound.wccg.build_wccg` runs them in float64
(``jax.enable_x64``) because bottleneck tests compare widths against ``W`` and float32 would move
a gap by ~1e-6 m on an 8 m workspace.
"""
from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

__all__ = ["aabb_gaps", "pack_polygons", "pair_distance", "pair_distances", "point_distances"]


def pack_polygons(polys, v_max: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Pack convex shapely Polygons into ``(verts f64[N, V, 2], nverts i32[N])``.

    Vertices are counter-clockwise (shapely's orientation is normalised by the scene parser); the
    closing vertex is dropped; rows are padded with their last vertex. ``V`` = ``v_max`` or the
    largest vertex count.
    """
    rings = [np.asarray(p.exterior.coords, np.float64)[:-1, :2] for p in polys]
    n = np.array([len(r) for r in rings], np.int32)
    v = int(v_max if v_max is not None else (n.max() if len(n) else 3))
    out = np.zeros((len(rings), v, 2), np.float64)
    for i, r in enumerate(rings):
        if _signed_area(r) < 0:
            r = r[::-1]
        out[i, :len(r)] = r
        out[i, len(r):] = r[-1]
    return out, n


def _signed_area(xy: np.ndarray) -> float:
    x, y = xy[:, 0], xy[:, 1]
    return 0.5 * float(np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y))


def aabb_gaps(lo, hi):
    """Bounding-box distance of every pair: ``lo, hi: f[N, 2]`` -> ``f[N, N]`` (0 if boxes touch).

    A lower bound on the polygon distance: pairs with ``aabb_gaps >= range`` need no exact test.
    """
    sep = jnp.maximum(0.0, jnp.maximum(lo[:, None, :] - hi[None, :, :], lo[None, :, :] - hi[:, None, :]))
    return jnp.sqrt(jnp.sum(sep * sep, axis=-1))


def _cross(ax, ay, bx, by):
    return ax * by - ay * bx


def _vertex_edge(p, e0, e1):
    """Closest points from every vertex ``p[V, 2]`` to every edge ``e0 -> e1 [V, 2]``: (d2, q)."""
    d = (e1 - e0)[None, :, :]
    rel = p[:, None, :] - e0[None, :, :]
    dd = jnp.sum(d * d, axis=-1)
    t = jnp.clip(jnp.sum(rel * d, axis=-1) / jnp.where(dd > 0, dd, 1.0), 0.0, 1.0)
    q = e0[None, :, :] + t[..., None] * d
    diff = p[:, None, :] - q
    return jnp.sum(diff * diff, axis=-1), q  # [V, V], [V, V, 2]


def _inside(p, e0, e1):
    """bool[V]: vertex ``p`` inside or on the convex CCW polygon with edges ``e0 -> e1``."""
    c = _cross((e1 - e0)[None, :, 0], (e1 - e0)[None, :, 1],
               p[:, None, 0] - e0[None, :, 0], p[:, None, 1] - e0[None, :, 1])
    return jnp.all(c >= 0.0, axis=-1)


def pair_distance(a, b):
    """Distance and closest points of two convex polygons ``a, b: f[V, 2]`` (packed, CCW).

    Returns ``(d f[], pa f[2], pb f[2])``; ``pa`` on ``a``, ``pb`` on ``b``, ``|pa - pb| = d``. When the
    polygons overlap ``d = 0`` and ``pa = pb`` is a point of the intersection (a vertex of one inside
    the other, or an edge crossing).
    """
    a1, b1 = jnp.roll(a, -1, axis=0), jnp.roll(b, -1, axis=0)
    d2_ab, q_ab = _vertex_edge(a, b, b1)  # a's vertices to b's edges
    d2_ba, q_ba = _vertex_edge(b, a, a1)
    i_ab, i_ba = jnp.argmin(d2_ab), jnp.argmin(d2_ba)
    v = a.shape[0]
    m_ab, m_ba = d2_ab.reshape(-1)[i_ab], d2_ba.reshape(-1)[i_ba]
    use_ab = m_ab <= m_ba
    pa = jnp.where(use_ab, a[i_ab // v], q_ba.reshape(-1, 2)[i_ba])
    pb = jnp.where(use_ab, q_ab.reshape(-1, 2)[i_ab], b[i_ba // v])
    d = jnp.sqrt(jnp.minimum(m_ab, m_ba))
    # Overlap: a vertex of one inside the other, or two edges crossing properly.
    in_a, in_b = _inside(a, b, b1), _inside(b, a, a1)
    da, db = (a1 - a), (b1 - b)
    o1 = _cross(da[:, None, 0], da[:, None, 1], b[None, :, 0] - a[:, None, 0], b[None, :, 1] - a[:, None, 1])
    o2 = _cross(da[:, None, 0], da[:, None, 1], b1[None, :, 0] - a[:, None, 0], b1[None, :, 1] - a[:, None, 1])
    o3 = _cross(db[None, :, 0], db[None, :, 1], a[:, None, 0] - b[None, :, 0], a[:, None, 1] - b[None, :, 1])
    o4 = _cross(db[None, :, 0], db[None, :, 1], a1[:, None, 0] - b[None, :, 0], a1[:, None, 1] - b[None, :, 1])
    crosses = (o1 * o2 < 0) & (o3 * o4 < 0)
    k = jnp.argmax(crosses.reshape(-1))
    ia, ib = k // v, k % v
    t = o3[ia, ib] / jnp.where(o3[ia, ib] != o4[ia, ib], o3[ia, ib] - o4[ia, ib], 1.0)
    x_point = a[ia] + t * da[ia]
    witness = jnp.where(jnp.any(in_a), a[jnp.argmax(in_a)],
                        jnp.where(jnp.any(in_b), b[jnp.argmax(in_b)], x_point))
    overlap = jnp.any(in_a) | jnp.any(in_b) | jnp.any(crosses)
    return (jnp.where(overlap, 0.0, d), jnp.where(overlap, witness, pa), jnp.where(overlap, witness, pb))


pair_distances = jax.jit(jax.vmap(pair_distance))
pair_distances.__doc__ = """``pair_distance`` over pairs: ``a, b: f[P, V, 2]`` ->
``(d f[P], pa f[P, 2], pb f[P, 2])``."""


@jax.jit
def point_distances(points, verts):
    """Distance ``f[P, N]`` from ``points: f[P, 2]`` to packed polygons ``verts: f[N, V, 2]`` (0 inside)."""
    e0, e1 = verts, jnp.roll(verts, -1, axis=1)

    def one(poly_e0, poly_e1):
        d2, _ = _vertex_edge(points, poly_e0, poly_e1)
        return jnp.where(_inside(points, poly_e0, poly_e1), 0.0, jnp.sqrt(jnp.min(d2, axis=-1)))

    return jax.vmap(one, out_axes=1)(e0, e1)
