"""``build_fabric`` and ``run_episode`` refuse bad inputs at the host level, before anything is
compiled: a ``TypeError`` naming the argument for a wrong type, one ``ValueError`` naming the field
for a Scene whose leaves disagree (a raw ``Scene(...)``) or whose counts are NaN, infinite or
negative. Never a traceback from inside JAX."""
from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxplan import FabricParams, Scene, SpillParams, build_fabric, random_scene, run_episode
from jaxplan.transport import EpisodeParams

GOOD = random_scene(0, (10, 10), 0.4)


def _raw(**changes) -> Scene:
    """A Scene from the raw constructor (no validation): ``GOOD``'s leaves with ``changes``."""
    leaves = dict(obj=GOOD.obj, target_mask=GOOD.target_mask, dist=GOOD.dist, tvec=GOOD.tvec,
                  cell_size=GOOD.cell_size, origin=GOOD.origin)
    leaves.update(changes)
    return Scene(**leaves)


def _counts(value, cell=(0, 0)) -> Scene:
    """``GOOD`` with one count replaced by ``value``, through the raw constructor."""
    obj = np.array(GOOD.obj)
    obj[cell] = value
    return _raw(obj=jnp.asarray(obj))


SHAPES = [
    (_raw(target_mask=GOOD.target_mask[:-1]), "Scene.target_mask"),
    (_raw(dist=GOOD.dist[:, :-2]), "Scene.dist"),
    (_raw(tvec=GOOD.tvec[..., 0]), "Scene.tvec"),
    (_raw(obj=GOOD.obj[:-1]), "Scene.target_mask"),          # obj is the reference: the others disagree
    (_raw(obj=GOOD.obj.ravel()), "Scene.obj"),
    (_raw(obj=jnp.zeros((0, 10))), "Scene.obj"),
    (_raw(cell_size=jnp.ones(2)), "Scene.cell_size"),
    (_raw(origin=jnp.zeros(3)), "Scene.origin"),
    (_raw(target_mask=None), "Scene.target_mask"),
]

CASES = [
    # build_fabric: types and shapes (static, so also checked under jit)
    ("build_fabric", dict(scene="default"), TypeError, r"scene: expected a Scene, got str.*builtin_scene\('default'\)"),
    ("build_fabric", dict(scene=None), TypeError, "scene: expected a Scene"),
    ("build_fabric", dict(scene=np.zeros((5, 5))), TypeError, "scene: expected a Scene"),
    ("build_fabric", dict(params="fast"), TypeError, "params: expected a FabricParams"),
    ("build_fabric", dict(params={"k": 4}), TypeError, "params: expected a FabricParams"),
    ("build_fabric", dict(params=FabricParams(k=0)), ValueError, r"FabricParams\.k"),
    *[("build_fabric", dict(scene=scene), ValueError, field) for scene, field in SHAPES],
    # run_episode: the same, and the counts' values (read once on the host)
    ("run_episode", dict(scene="default"), TypeError, "scene: expected a Scene"),
    ("run_episode", dict(params="fast"), TypeError, "params: expected a FabricParams"),
    ("run_episode", dict(scene=_counts(np.nan)), ValueError, r"Scene\.obj: .*1 NaN value"),
    ("run_episode", dict(scene=_counts(np.inf, (2, 3))), ValueError, r"Scene\.obj: .*infinite.*row 2, col 3"),
    ("run_episode", dict(scene=_counts(-3.0)), ValueError, r"Scene\.obj: .*negative"),
    ("run_episode", dict(scene=_raw(obj=GOOD.obj + 0j)), ValueError, r"Scene\.obj: counts must be numbers"),
    ("run_episode", dict(spill="lam=0.05"), ValueError, "spill: expected a SpillParams"),
    ("run_episode", dict(spill=SpillParams(lam=float("nan"))), ValueError, "lam"),
    ("run_episode", dict(episode=EpisodeParams(max_pushes=-1)), ValueError, r"EpisodeParams\.max_pushes"),
    ("run_episode", dict(params=FabricParams(temperature=0.5)), ValueError, r"FabricParams\.temperature"),
    *[("run_episode", dict(scene=scene), ValueError, field) for scene, field in SHAPES],
]


def _call(entry: str, kwargs: dict):
    args = dict(scene=GOOD, params=FabricParams())
    args.update(kwargs)
    if entry == "build_fabric":
        return build_fabric(args["scene"], args["params"])
    return run_episode(args["scene"], args["params"], args.get("spill"), args.get("episode"))


@pytest.mark.parametrize("entry, kwargs, error, message", CASES)
def test_bad_inputs_are_refused_naming_the_argument(entry, kwargs, error, message):
    with pytest.raises(error, match=message) as caught:
        _call(entry, kwargs)
    assert type(caught.value) is error            # not a subclass raised from deep inside JAX


def test_mismatched_shapes_are_refused_under_jit_before_compiling():
    with pytest.raises(ValueError, match=r"Scene\.dist: shape \(10, 8\) disagrees with Scene\.obj's \(10, 10\)"):
        jax.jit(build_fabric)(_raw(dist=GOOD.dist[:, :-2]), FabricParams())


def test_traced_counts_pass_the_shape_check():
    """Inside jit the counts cannot be read; the check looks at shapes only and lets tracing go on."""
    seen = []

    def probe(obj):
        Scene.check(GOOD.with_obj(obj))
        seen.append(obj.shape)
        return obj

    jax.jit(probe)(GOOD.obj)
    assert seen == [(10, 10)]


def test_a_good_raw_scene_passes():
    Scene.check(_raw())
