"""Body outlines for the search's progress tests and push directions."""
from __future__ import annotations

import numpy as np
import shapely
from shapely import affinity

from jaxplan.pusharound.scene import PushScene

__all__ = ["BodyOutlines", "unit"]


class BodyOutlines:
    """Body outlines for the progress tests (body frame for movables, world for the rest)."""

    def __init__(self, scene: PushScene):
        self.scene = scene
        self.m = len(scene.movables)
        self.body_frame = [shapely.union_all(list(mv.pieces)) for mv in scene.movables]
        self.fixed = [f.polygon for f in scene.fixed]
        x0, y0, x1, y1 = scene.workspace
        t = 1.0
        self.walls = shapely.union_all([shapely.box(x0 - t, y0 - t, x0, y1 + t),
                                        shapely.box(x1, y0 - t, x1 + t, y1 + t),
                                        shapely.box(x0, y0 - t, x1, y0), shapely.box(x0, y1, x1, y1 + t)])

    def movable(self, m: int, pose):
        """World polygon of movable ``m`` at ``pose`` (x [m], y [m], yaw [rad])."""
        x, y, psi = (float(v) for v in pose)
        return affinity.translate(affinity.rotate(self.body_frame[m], psi, origin=(0, 0), use_radians=True), x, y)

    def body(self, b: int, poses):
        """World polygon of WCCG body ``b`` (movables 0..M-1, fixed M..M+F-1, walls M+F) with the
        movables at ``poses`` f[M, 3]."""
        if b < self.m:
            return self.movable(b, poses[b])
        if b < self.m + len(self.fixed):
            return self.fixed[b - self.m]
        return self.walls


def unit(v) -> np.ndarray:
    """``v`` (f[2]) scaled to length 1; (1, 0) when it is shorter than 1e-12."""
    v = np.asarray(v, np.float64)
    n = float(np.linalg.norm(v))
    return v / n if n > 1e-12 else np.array([1.0, 0.0])
