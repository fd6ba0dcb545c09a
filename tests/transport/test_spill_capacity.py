"""The capacity-aware spill evaluator (jaxplan.transport.spillage.capacity) against its serial reference; its limits,
gradients, vmap over parameter sets, plugging into execute, and the fit."""
from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from jaxplan import Scene, box
from jaxplan.reference import execute as ref_ex
from jaxplan.reference import spill_capacity as ref_sc
from jaxplan.transport import execute as ex
from jaxplan.transport import spillage as sp
from jaxplan.transport.spillage import capacity as sc
from jaxplan.transport.spillage import fit as spill_fit

SETTINGS = settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
SLOTS = 8           # waypoint slots: one compiled shape for every example
_MOVES = [(1, 0), (0, 1), (-1, 0), (0, -1), (1, 1), (1, -1), (-1, 1), (-1, -1)]


def _evaluate(points, n, pickup, params):
    delivered, spill, _ = sp.evaluate_route(jnp.asarray(points), n, jnp.asarray(pickup), params, sc.capacity_spill)
    return delivered, spill


_evaluate_jit = jax.jit(_evaluate)


@st.composite
def routes(draw):
    """A walk of 2..SLOTS cell centres without immediate reversals, padded to SLOTS, and its pickups."""
    n = draw(st.integers(2, SLOTS))
    xy = [np.array([4.5, 4.5])]
    prev = None
    for _ in range(n - 1):
        k = draw(st.sampled_from([m for m in _MOVES if prev is None or m != (-prev[0], -prev[1])]))
        xy.append(xy[-1] + k)
        prev = k
    pts = np.stack(xy + [xy[-1]] * (SLOTS - n)).astype(np.float32)
    pick = np.array([draw(st.integers(0, 12)) if i < n - 1 else 0 for i in range(SLOTS)], np.float32)
    return pts, n, pick


params_st = st.builds(
    lambda c, lam, mu, t, thr, miss, sat: sc.CapacitySpillParams(
        capacity=np.float32(c), lam=np.float32(lam), mu=np.float32(mu), temperature=np.float32(t),
        threshold=np.float32(thr), miss=np.float32(miss), turn_saturation=np.float32(sat)),
    st.floats(0.5, 40.0), st.floats(0.0, 2.0), st.floats(0.0, 0.5), st.floats(0.05, 3.0),
    st.sampled_from([0.0, 1e-3, 0.3]), st.sampled_from([0.0, 0.05, 0.3, 1.5]),
    st.sampled_from([float("inf"), 0.5, 3.0, 20.0]))


def _reference(pts, n, pick, p):
    samples = ref_ex.catmull_rom_samples([tuple(map(float, q)) for q in pts[:n]], p.samples_per_step)
    return ref_sc.capacity_spill_along(samples, [float(x) for x in pick], capacity=float(p.capacity),
                                       lam=float(p.lam), mu=float(p.mu), temperature=float(p.temperature),
                                       threshold=float(p.threshold), samples_per_step=p.samples_per_step,
                                       miss=float(p.miss), turn_saturation=float(p.turn_saturation))


@SETTINGS
@given(route=routes(), params=params_st)
def test_capacity_spill_equals_serial_reference(route, params):
    pts, n, pick = route
    assert_equals_reference(_evaluate_jit(pts, n, pick, params), _reference(pts, n, pick, params), n, pick)


def assert_equals_reference(evaluated, reference, n, pick):
    """An evaluator's ``(delivered, spill[N])`` equals the serial reference's on the route's samples,
    is 0 on the padding, and keeps mass: delivered + spilled = collected."""
    (delivered, spill), (ref_delivered, ref_spill) = evaluated, reference
    m = len(ref_spill)
    tol = 1e-3 * (1.0 + pick.sum())
    assert abs(float(delivered) - ref_delivered) <= tol
    np.testing.assert_allclose(np.asarray(spill)[:m], ref_spill, atol=tol)
    assert np.all(np.asarray(spill)[m:] == 0)
    assert abs(float(delivered) + float(np.sum(spill)) - float(pick[: n - 1].sum())) <= tol


def _straight(n_cells, per_cell):
    pts = np.stack([np.array([0.5 + i, 0.5]) for i in range(n_cells + 1)] + [np.array([0.5 + n_cells, 0.5])] * 2)
    pick = np.zeros(pts.shape[0], np.float32)
    pick[:n_cells] = per_cell
    return pts.astype(np.float32), n_cells + 1, pick


@pytest.mark.parametrize("jit", [False, True], ids=["eager", "jit"])
def test_blade_holds_at_most_its_capacity(jit):
    ev = _evaluate_jit if jit else _evaluate
    pts, n, pick = _straight(6, 5.0)                  # 30 objects on a straight route
    hard = sc.CapacitySpillParams(capacity=12.0, lam=0.0, mu=0.0, temperature=0.01)
    assert float(ev(pts, n, pick, hard)[0]) == pytest.approx(12.0, abs=0.02)
    roomy = hard.replace(capacity=100.0)
    assert float(ev(pts, n, pick, roomy)[0]) == pytest.approx(30.0, abs=0.02)
    # a softer limit carries a little less than the hard one near capacity, never more than collected
    soft = float(ev(pts, n, pick, hard.replace(temperature=2.0))[0])
    assert 9.0 < soft < 12.0
    # loss per distance: a constant fraction per unit of travel after the last pickup
    lossy = float(ev(pts, n, pick, roomy.replace(mu=0.1))[0])
    assert 0.0 < lossy < 30.0


def test_large_capacity_and_no_distance_loss_is_the_curvature_model():
    pts = np.array([[0.5, 0.5], [1.5, 0.5], [2.5, 0.5], [2.5, 1.5], [2.5, 2.5], [3.5, 3.5], [3.5, 3.5]], np.float32)
    pick = np.array([4, 3, 5, 2, 1, 0, 0], np.float32)
    cap = sc.CapacitySpillParams(capacity=1e4, lam=0.4, mu=0.0, temperature=0.5)
    curv = sp.SpillParams(lam=0.4)
    a = sp.evaluate_route(pts, 6, pick, cap, sc.capacity_spill)
    b = sp.evaluate_route(pts, 6, pick, curv, sp.curvature_spill)
    np.testing.assert_allclose(float(a[0]), float(b[0]), atol=1e-4)
    np.testing.assert_allclose(np.asarray(a[1]), np.asarray(b[1]), atol=1e-4)


def test_gradients_are_finite_and_vmap_over_parameter_sets_matches_a_loop():
    pts, n, pick = _straight(5, 4.0)
    pts = pts.copy()
    pts[3:, 1] += 1.0          # a bend, so lam matters too
    f32 = np.float32
    base = sc.CapacitySpillParams(capacity=f32(10.0), lam=f32(0.3), mu=f32(0.05), temperature=f32(0.5),
                                  threshold=f32(1e-3))
    grad_p = jax.grad(lambda p: _evaluate_jit(pts, n, pick, p)[0])(base)
    for name in ("capacity", "lam", "mu", "temperature", "miss", "turn_saturation"):
        g = float(getattr(grad_p, name))
        assert np.isfinite(g), name
    assert float(grad_p.capacity) > 0 and float(grad_p.mu) < 0 and float(grad_p.lam) < 0
    assert float(grad_p.miss) < 0
    # a finite saturation load: more of it spills more in the turn
    finite = base.replace(turn_saturation=f32(5.0), miss=f32(0.2))
    grad_f = jax.grad(lambda p: _evaluate_jit(pts, n, pick, p)[0])(finite)
    assert all(np.isfinite(float(getattr(grad_f, k))) for k in ("miss", "turn_saturation", "lam"))
    assert float(grad_f.turn_saturation) < 0 and float(grad_f.miss) < 0
    grad_w = jax.grad(lambda w: _evaluate_jit(w, n, pick, base)[0])(jnp.asarray(pts))   # padded: n < slots
    assert np.all(np.isfinite(np.asarray(grad_w)))
    caps = jnp.array([3.0, 8.0, 30.0], jnp.float32)
    batched = jax.vmap(lambda c: _evaluate_jit(pts, n, pick, base.replace(capacity=c))[0])(caps)
    looped = [float(_evaluate_jit(pts, n, pick, base.replace(capacity=f32(c)))[0]) for c in caps]
    np.testing.assert_allclose(np.asarray(batched), looped, rtol=1e-5, atol=1e-5)


def test_capacity_params_plug_into_execute():
    obj = np.zeros((6, 9), np.float32)
    obj[2, 1:5] = 6.0
    scene = Scene.from_arrays(obj, box(7.0, 0.0, 9.0, 6.0), cell_size=1.0)
    route = ex.Route(cells=jnp.array([[2, c] for c in range(1, 8)] + [[-1, -1]] * 3, jnp.int32),
                     n_cells=jnp.int32(7), fallback=jnp.bool_(False), end=jnp.array([7.5, 2.5], jnp.float32))
    params = sc.CapacitySpillParams(capacity=10.0, lam=0.05, mu=0.0, temperature=0.1)
    new_obj, push = ex.execute_jit(scene, route, params, sc.capacity_spill)
    assert float(push.delivered) == pytest.approx(10.0, abs=0.2)
    assert float(np.sum(new_obj)) == pytest.approx(float(np.sum(obj)), abs=1e-3)


def test_fit_recovers_a_capacity_from_model_generated_deliveries():
    rng = np.random.default_rng(3)
    pts, ns, picks = [], [], []
    for k in range(6):
        p, n, pick = _straight(4 + k % 3, float(rng.integers(2, 8)))
        pts.append(p[:9] if p.shape[0] >= 9 else np.concatenate([p, np.repeat(p[-1:], 9 - p.shape[0], 0)]))
        ns.append(n)
        picks.append(np.concatenate([pick, np.zeros(9 - pick.shape[0], np.float32)])[:9])
    pts, ns, picks = np.stack(pts), np.array(ns), np.stack(picks)
    truth = sc.CapacitySpillParams(capacity=11.0, lam=0.0, mu=0.02, temperature=0.5)
    obs = np.asarray(spill_fit.predict_delivered(pts, ns, picks, truth))
    fit = spill_fit.fit_capacity(pts, ns, picks, obs, steps=100,
                                 grid={"capacity": (6.0, 16.0), "lam": (0.0,), "mu": (0.0, 0.05)})
    pred = np.asarray(spill_fit.predict_delivered(pts, ns, picks, fit.params))
    assert np.all(np.isfinite(fit.loss))
    assert np.sqrt(np.mean((pred - obs) ** 2)) < 0.3
    assert fit.params.capacity == pytest.approx(11.0, abs=1.0)


@pytest.mark.parametrize("field,value", [("capacity", 0.0), ("mu", -0.1), ("temperature", float("nan")),
                                         ("lam", -1.0), ("miss", -0.5), ("miss", float("inf")),
                                         ("turn_saturation", 0.0), ("turn_saturation", float("nan"))])
def test_bad_capacity_params_name_the_field(field, value):
    with pytest.raises(ValueError, match=field):
        sc.validate_capacity_params(sc.CapacitySpillParams(**{field: value}))


def test_capacity_params_are_a_spill_params_pytree():
    p = sc.CapacitySpillParams(capacity=7.0, samples_per_step=4)
    assert isinstance(p, sp.SpillParams)
    sp.validate_spill_params(p)
    leaves, tree = jax.tree_util.tree_flatten(p)
    back = jax.tree_util.tree_unflatten(tree, leaves)
    assert back == p and back.samples_per_step == 4 and 7.0 in leaves


def test_evaluator_for_picks_the_model_the_params_are_for():
    assert sp.evaluator_for(sc.CapacitySpillParams(capacity=5.0)) is sc.capacity_spill
    assert sp.evaluator_for(sp.SpillParams()) is sp.curvature_spill


def _zigzag():
    """A route that turns at every waypoint (east, north-east, east, ...) with 3 objects per cell."""
    xy = [np.array([0.5, 0.5])]
    for k in range(6):
        xy.append(xy[-1] + (np.array([1.0, 0.0]) if k % 2 == 0 else np.array([1.0, 1.0])))
    pts = np.stack(xy + [xy[-1]]).astype(np.float32)
    pick = np.array([3.0] * 6 + [0.0, 0.0], np.float32)
    return pts, 7, pick


def test_defaults_of_the_turning_terms_are_the_three_term_model():
    pts, n, pick = _zigzag()
    three = sc.CapacitySpillParams(capacity=12.0, lam=0.3, mu=0.02, temperature=0.5)
    assert float(three.miss) == 0.0 and np.isinf(three.turn_saturation)
    ref_d, ref_s = _reference(pts, n, pick, three)
    # the same recurrence without the two terms, written out: the turning fraction is lam |turn|
    samples = ref_ex.catmull_rom_samples([tuple(map(float, q)) for q in pts[:n]], three.samples_per_step)
    plain_d, _ = ref_sc.capacity_spill_along(samples, [float(x) for x in pick], capacity=12.0, lam=0.3, mu=0.02,
                                             temperature=0.5, threshold=float(three.threshold))
    assert ref_d == pytest.approx(plain_d, abs=1e-9)
    assert float(_evaluate_jit(pts, n, pick, three)[0]) == pytest.approx(ref_d, abs=1e-3)


@pytest.mark.parametrize("jit", [False, True], ids=["eager", "jit"])
def test_the_blade_misses_objects_only_where_the_route_turns(jit):
    ev = _evaluate_jit if jit else _evaluate
    roomy = sc.CapacitySpillParams(capacity=1e4, lam=0.0, mu=0.0, temperature=0.5)
    pts, n, pick = _straight(6, 5.0)
    assert float(ev(pts, n, pick, roomy.replace(miss=0.5))[0]) == pytest.approx(30.0, abs=1e-3)
    pts, n, pick = _zigzag()
    delivered, spill = ev(pts, n, pick, roomy.replace(miss=0.2))
    samples = sp.sample_route(jnp.asarray(pts), n, roomy.samples_per_step)
    missed = sc.missed_objects(samples, sp.pickups_per_sample(samples, jnp.asarray(pick)), 0.2, roomy.samples_per_step)
    # only the misses leave the route, at the samples where their cells' objects are picked up
    assert float(jnp.sum(missed)) > 0.5
    np.testing.assert_allclose(np.asarray(spill)[: missed.shape[0]], np.asarray(missed), atol=1e-5)
    assert float(delivered) == pytest.approx(float(pick.sum() - jnp.sum(missed)), abs=1e-3)
    # each cell loses min(1, miss * near) of its objects: 45 degrees each way at the zigzag's corners
    near = np.asarray(sc.turning_near_pickups(samples, roomy.samples_per_step))[np.asarray(samples.first)][:6]
    assert np.all(near[1:] > 0.5) and np.all(near < np.pi / 2)


def test_a_finite_saturation_load_bounds_the_turning_loss_of_a_full_blade():
    pts, n, _ = _zigzag()
    light = np.array([0.05] * 6 + [0.0, 0.0], np.float32)     # 0.3 objects in all: far below S
    heavy = light * 400
    prop = sc.CapacitySpillParams(capacity=1e4, lam=0.2, mu=0.0, temperature=0.5)
    sat = prop.replace(turn_saturation=2.0)
    lost = lambda pick, p: float(pick.sum() - _evaluate_jit(pts, n, pick, p)[0])  # noqa: E731
    # a light load spills nearly the proportional share, a heavy one far less than it
    assert lost(light, sat) == pytest.approx(lost(light, prop), rel=0.2)
    assert lost(heavy, sat) < 0.2 * lost(heavy, prop)
    assert lost(heavy, sat) > lost(light, sat)


def test_fit_miss_recovers_the_rate_from_left_behind_objects():
    pts, ns, picks = [], [], []
    for scale in (1.0, 2.0, 0.5):
        p, n, k = _zigzag()
        pts.append(p), ns.append(n), picks.append(k * scale)
    pts, ns, picks = np.stack(pts), np.array(ns), np.stack(picks)
    left = np.asarray(spill_fit.predict_missed(pts, ns, picks, 0.18))
    assert np.all(left > 0)
    assert spill_fit.fit_miss(pts, ns, picks, left) == pytest.approx(0.18, abs=1e-3)
    # fit_capacity with left_behind holds miss there and fits the rest on deliveries
    truth = sc.CapacitySpillParams(capacity=1e3, lam=0.1, mu=0.0, temperature=0.5, miss=0.18, turn_saturation=3.0)
    obs = np.asarray(spill_fit.predict_delivered(pts, ns, picks, truth))
    fit = spill_fit.fit_capacity(pts, ns, picks, obs, steps=150, fields=("lam", "turn_saturation"), left_behind=left,
                          base=sc.CapacitySpillParams(capacity=1e3))
    assert fit.params.miss == pytest.approx(0.18, abs=1e-3)
    pred = np.asarray(spill_fit.predict_delivered(pts, ns, picks, fit.params))
    assert np.sqrt(np.mean((pred - obs) ** 2)) < 0.1


def test_fit_capacity_names_a_bad_field_or_a_missing_grid():
    pts, n, pick = _straight(3, 2.0)
    args = (pts[None], np.array([n]), pick[None], np.array([5.0]))
    with pytest.raises(ValueError, match="fields"):
        spill_fit.fit_capacity(*args, fields=("capacity", "speed"))
    with pytest.raises(ValueError, match="grid"):
        spill_fit.fit_capacity(*args, fields=("capacity",), grid={"lam": (0.0,)})


def test_execute_keeps_the_missed_objects_on_the_grid():
    obj = np.zeros((8, 10), np.float32)
    cells = [[1, 1], [1, 2], [2, 3], [2, 4], [3, 5], [3, 6]]      # a zigzag: a turn at every cell
    for r, c in cells:
        obj[r, c] = 4.0
    scene = Scene.from_arrays(obj, box(7.0, 2.0, 10.0, 6.0), cell_size=1.0)
    route = ex.Route(cells=jnp.array(cells + [[3, 7]] + [[-1, -1]] * 3, jnp.int32), n_cells=jnp.int32(7),
                     fallback=jnp.bool_(False), end=jnp.array([7.5, 3.5], jnp.float32))
    plain = sc.CapacitySpillParams(capacity=100.0, lam=0.05, mu=0.0, temperature=0.5)
    turning = plain.replace(miss=0.3, turn_saturation=2.0)
    _, push_plain = ex.execute_jit(scene, route, plain, sc.capacity_spill)
    new_obj, push = ex.execute_jit(scene, route, turning, sc.capacity_spill)
    assert float(push.delivered) < float(push_plain.delivered)
    # mass: what stays on the grid (the misses included) plus what arrives is what was there
    target = np.asarray(scene.target_mask)
    outside = float(np.sum(np.where(target, 0.0, np.asarray(new_obj))))
    assert outside + float(push.delivered) == pytest.approx(float(obj.sum()), abs=1e-3)
    assert float(np.sum(new_obj)) == pytest.approx(float(obj.sum()), abs=1e-3)


def test_rover_fit_is_the_benchmark_s_in_sample_fit():
    """ROVER_FIT carries the committed benchmark's fit (experiments/results/rover.json) to 4 digits."""
    import json
    from pathlib import Path

    results = Path(__file__).resolve().parents[2] / "experiments" / "results" / "rover.json"
    fitted = json.loads(results.read_text())["fits"]["turning"]["in_sample"]["params"][0]
    for field in ("capacity", "lam", "mu", "temperature", "miss", "turn_saturation"):
        assert float(getattr(sc.ROVER_FIT, field)) == pytest.approx(fitted[field], rel=1e-3, abs=1e-6), field
    sc.validate_capacity_params(sc.ROVER_FIT)
