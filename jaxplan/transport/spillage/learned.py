"""A spill model learned from physics: a small network sets the loss rates along the route.

The curvature and capacity models fix the form of the loss and fit a few constants to it. Fitted to
the MuJoCo rover on many scenes, they miss how the loss depends on where the route turns, how its
turns follow each other and how far the load still has to go. This model keeps the sequential form
(the load at a sample depends on what was lost before it) and lets a network with one hidden layer
read the route's shape around each spline sample:

    features_i = [|turn_i| m, window |turn|, |window turn|, pickup_i / L, near_i,
                  min(to_go_i / D, C), min(done_i / D, C)]
    a_i        = tanh(features_i @ w1 + b1) @ w2 + b2                     (three outputs per sample)
    missed_i   = sigmoid(a_i[2]) * pickup_i
    load      <- load + pickup_i - missed_i
    rate_i     = dl_i * softplus(a_i[0] + load_w[0] load / L) + |turn_i| * softplus(a_i[1] + load_w[1] load / L)
    spill_i    = load * (1 - exp(-rate_i)),   set to 0 when below ``threshold``
    load      <- load - spill_i
    spill_i   += missed_i

``m`` is ``samples_per_step``; the windows sum the turning over one step before and after the sample
(signed and then absolute for ``|window turn|``: a zigzag turns much and nets little); ``near_i`` is
the turning within half a step of the cell picked up there (``turning_near_pickups``); ``to_go`` and
``done`` are the route's length still ahead and already behind, ``dl_i`` the distance from the previous
sample (``chord_lengths``); ``L = LOAD_SCALE`` objects, ``D = LENGTH_SCALE`` world units, and
``C = DISTANCE_CAP``: past the longest routes of its data the network sees no longer distances. The rates
are a loss per world unit and per radian, so the spilled fraction of a stretch barely depends on how
densely the spline is sampled; the load enters them linearly inside the softplus, so the network
runs on every sample at once and the sequential scan stays as cheap as the capacity model's.
Delivered + spilled = collected holds, as in every model. The parameters are arrays of a pytree:
``jax.grad`` and ``jax.vmap`` go through them; ``jaxplan.tune.fit_learned`` fits them with optax.
"""
from __future__ import annotations

import dataclasses
from typing import Any, ClassVar

import jax
import jax.numpy as jnp
import numpy as np

from jaxplan.transport.spillage import base as spillage
from jaxplan.transport.spillage.capacity import turning_near_pickups

__all__ = ["DISTANCE_CAP", "FEATURES", "HIDDEN", "LEARNED_FIT", "LENGTH_SCALE", "LOAD_SCALE", "LearnedSpillParams",
           "learned_spill", "load_learned", "sample_features", "validate_learned_params"]

LOAD_SCALE = 10.0     # objects: load and pickup features are in units of this
LENGTH_SCALE = 10.0   # world units: the distance features are in units of this
# The distance features stop growing here (in LENGTH_SCALE units): the fit's routes are at most ~25
# world units long, and a network read beyond its data extrapolates.
DISTANCE_CAP = 2.5
HIDDEN = 8            # hidden units of the default (unfitted) parameters
FEATURES = ("turn", "window_turn", "window_net_turn", "pickup", "near_turn", "to_go", "done")
_NEUTRAL_BIAS = (-4.6, -3.0, -3.0)   # ~1% lost per world unit, ~5% per radian, ~5% of a cell missed


def _zeros(*shape):
    return dataclasses.field(default_factory=lambda: np.zeros(shape, np.float32))


@dataclasses.dataclass(frozen=True)
class LearnedSpillParams(spillage.SpillParams):
    """Parameters of the learned spill model (a ``SpillParams`` with five more traced arrays).

    Traced (besides ``lam``, ``threshold`` and ``temperature`` of ``SpillParams``; it reads only
    ``threshold``), F = ``len(FEATURES)``, H hidden units (any H; from the arrays' shapes):
      w1: f32[F, H], b1: f32[H]: the hidden layer.  w2: f32[H, 3], b2: f32[3]: the three outputs
        (log-rate per world unit, log-rate per radian, logit of the fraction missed).
      load_w: f32[2], how the two rates grow with the load (per ``LOAD_SCALE`` objects).
    The defaults are a neutral start (constant rates: about 1% lost per world unit, 5% per radian and
    5% of each cell missed), not a fitted rover; ``LEARNED_FIT`` is the fit to the MuJoCo rover.
    """

    model: ClassVar[str] = "learned"
    threshold: Any = 0.0
    w1: Any = _zeros(len(FEATURES), HIDDEN)
    b1: Any = _zeros(HIDDEN)
    w2: Any = _zeros(HIDDEN, 3)
    b2: Any = dataclasses.field(default_factory=lambda: np.array(_NEUTRAL_BIAS, np.float32))
    load_w: Any = _zeros(2)

    # field by field with array equality (the generated __eq__ would compare arrays with ==), so that
    # concrete parameters compare and hash as values, like the scalar models' do
    def __eq__(self, other):
        if type(other) is not type(self):
            return NotImplemented
        return all(np.array_equal(np.asarray(getattr(self, f.name)), np.asarray(getattr(other, f.name)))
                   for f in dataclasses.fields(self))

    def __hash__(self):
        return hash(tuple(np.asarray(getattr(self, f.name)).tobytes() for f in dataclasses.fields(self)))


_ARRAYS = ("w1", "b1", "w2", "b2", "load_w")
jax.tree_util.register_dataclass(LearnedSpillParams, data_fields=["lam", "threshold", "temperature", *_ARRAYS],
                                 meta_fields=["samples_per_step", "enabled", "spline_alpha"])


def validate_learned_params(params: LearnedSpillParams) -> None:
    """Raise ``ValueError`` naming the field for bad concrete parameters (shapes, non-finite values)."""
    if not isinstance(params, LearnedSpillParams):
        raise ValueError(f"learned_spill: expected a LearnedSpillParams, got {type(params).__name__}. "
                         "Use jaxplan.transport.spillage.LEARNED_FIT or fit one with jaxplan.tune.fit_learned.")
    spillage.validate_spill_params(params)
    shapes = {name: np.shape(getattr(params, name)) for name in _ARRAYS}
    hidden = shapes["w1"][1] if len(shapes["w1"]) == 2 else -1
    expected = {"w1": (len(FEATURES), hidden), "b1": (hidden,), "w2": (hidden, 3), "b2": (3,), "load_w": (2,)}
    for name in _ARRAYS:
        if shapes[name] != expected[name] or hidden < 1:
            raise ValueError(f"LearnedSpillParams.{name}: expected shape {expected[name]} (F = {len(FEATURES)} "
                             f"features, H = w1.shape[1] >= 1 hidden units); got {shapes[name]}.")
        value = getattr(params, name)
        if not isinstance(value, jax.core.Tracer) and not np.all(np.isfinite(np.asarray(value))):
            raise ValueError(f"LearnedSpillParams.{name}: must be finite; got {value!r}.")


def _window_sum(x, half: int):
    """f32[N]: sum of ``x[i - half .. i + half]`` (clipped at the ends), by a cumulative sum."""
    c = jnp.concatenate([jnp.zeros((1,), x.dtype), jnp.cumsum(x)])
    n = x.shape[0]
    i = jnp.arange(n)
    return c[jnp.minimum(i + half + 1, n)] - c[jnp.maximum(i - half, 0)]


def sample_features(samples: spillage.PathSamples, pickup, samples_per_step: int):
    """``(features f32[N, F], chord f32[N])``: the network's inputs at each sample (``FEATURES``, module
    docstring) and the distance from the previous sample (world units); 0 on padding samples."""
    m = samples_per_step
    turn = jnp.abs(samples.turn)
    chord = spillage.chord_lengths(samples)
    done = jnp.cumsum(chord)
    to_go = done[-1] - done
    feats = jnp.stack([turn * m, _window_sum(turn, m), jnp.abs(_window_sum(samples.turn, m)), pickup / LOAD_SCALE,
                       turning_near_pickups(samples, m), jnp.minimum(to_go / LENGTH_SCALE, DISTANCE_CAP),
                       jnp.minimum(done / LENGTH_SCALE, DISTANCE_CAP)], -1)
    return jnp.where(samples.valid[:, None], feats, 0.0), chord


def learned_spill(samples: spillage.PathSamples, pickup, params: LearnedSpillParams):
    """``(delivered f32[], spill f32[N])`` in objects (module docstring).

    samples: the route's spline samples (``spillage.sample_route``); pickup: f32[N] objects picked
    up at each sample.
    """
    feats, chord = sample_features(samples, pickup, params.samples_per_step)
    hidden = jnp.tanh(feats @ jnp.asarray(params.w1, jnp.float32) + jnp.asarray(params.b1, jnp.float32))
    out = hidden @ jnp.asarray(params.w2, jnp.float32) + jnp.asarray(params.b2, jnp.float32)   # [N, 3]
    missed = jnp.where(pickup > 0, jax.nn.sigmoid(out[:, 2]), 0.0) * pickup
    turn = jnp.abs(samples.turn)
    load_w = jnp.asarray(params.load_w, jnp.float32) / LOAD_SCALE

    def step(load, x):
        pick, a, t, dl = x
        load = load + pick
        rate = dl * jax.nn.softplus(a[0] + load_w[0] * load) + t * jax.nn.softplus(a[1] + load_w[1] * load)
        spill = load * -jnp.expm1(-rate)
        spill = jnp.where(spill >= params.threshold, spill, 0.0)
        return load - spill, spill

    delivered, spill = jax.lax.scan(step, jnp.float32(0.0), (pickup - missed, out[:, :2], turn, chord))
    return delivered, spill + missed


spillage.register("learned", learned_spill)


def load_learned(path) -> LearnedSpillParams:
    """``LearnedSpillParams`` from a JSON file with the arrays ``w1, b1, w2, b2, load_w`` (as
    ``experiments/spill_models.py --write-fit`` writes them), validated."""
    import json
    from pathlib import Path

    try:
        raw = json.loads(Path(path).read_text())
        params = LearnedSpillParams(**{name: np.asarray(raw[name], np.float32) for name in _ARRAYS})
    except (OSError, ValueError, KeyError, TypeError) as err:
        raise ValueError(f"{path}: not a learned spill model ({err}); it needs the arrays {list(_ARRAYS)}.") from err
    validate_learned_params(params)
    return params


def _shipped_fit() -> LearnedSpillParams:
    from importlib.resources import files

    return load_learned(files("jaxplan.transport.spillage").joinpath("learned_fit.json"))


# The fit of ``experiments/spill_models.py`` to the MuJoCo rover (``RoverConfig()``, the C engine) on
# the training scenes of ``experiments/data/spill.npz``; its held-out scores are in
# ``experiments/results/spill_models.md``. Another rover needs its own fit (``jaxplan.tune.fit_learned``).
LEARNED_FIT = _shipped_fit()
