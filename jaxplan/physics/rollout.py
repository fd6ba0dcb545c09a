"""One rollout interface, two engines: MJX (``jax.vmap`` under ``jax.jit``) and the MuJoCo C engine.

A rollout is: an ``MjModel``, a batch of B initial states (``qpos f[B, nq]``, ``qvel f[B, nv]``), a
closed-loop control policy with per-element parameters, and a horizon of T control ticks of
``substeps`` physics steps each (the control is held constant over a tick). Both engines return the
same :class:`Trajectory`: the state at every tick, the controls applied, and per element whether the
physics stayed finite and inside the world box.

The policy is one pure JAX function for both engines::

    policy(params, pstate, qpos f[nq], qvel f[nv], time f[]) -> (ctrl f[nu], pstate)

``params`` and ``pstate`` are pytrees (one element; the batch has a leading B axis). MJX traces it
inside the scan; the C engine calls a jitted ``vmap`` of it once per tick on the host and steps every
element with ``mj_step`` in a thread pool (``mj_step`` releases the GIL). An open-loop schedule is the
policy :func:`schedule_policy`.

Divergence: an element whose ``qpos``/``qvel`` stops being finite, or whose free bodies leave
``bounds``, is marked ``finite = False`` from that tick on (``first_bad``); the batch carries on. The
C engine stops stepping such an element (its later ticks repeat the last good state); MJX keeps
stepping it (vmapped lanes are independent, so NaNs never leak to other elements) but the flag is the
same. MuJoCo's auto-reset on bad accelerations is disabled in the C engine so that a blow-up shows up
as NaN instead of a silent jump back to the initial pose.

Model parameters per element: ``run(..., model_fields={"geom_friction": f[B, ngeom, 3]})`` gives each
element its own values of any numeric ``MjModel`` field (friction, masses, gains, ...). MJX vmaps over
them (one compiled program per horizon and set of field names, so new values do not recompile); the C
engine steps each element with its own model copy.

Engines agree within the tolerances of ``docs/physics.md`` (MJX runs in float32, the C engine in
float64; contact-rich scenes are chaotic, so per-particle states differ while aggregate verdicts agree).
"""
from __future__ import annotations

import concurrent.futures
import logging
import os
import time
from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

__all__ = ["BACKENDS", "FAST_COMPILE", "Trajectory", "Simulator", "default_backend", "warp_available",
           "schedule_policy", "free_qpos_addresses"]

# XLA options for a large MJX program on a CPU: LLVM's expensive passes off (the nominal PushAround
# scene's compile with them: docs/physics.md).
FAST_COMPILE = {"xla_backend_optimization_level": 0, "xla_llvm_disable_expensive_passes": True}

Policy = Callable[[Any, Any, jax.Array, jax.Array, jax.Array], tuple]


class Trajectory(NamedTuple):
    """What a batched rollout returns (numpy arrays, float64 from C and float32 from MJX).

    qpos: f[B, T+1, nq], state at tick 0 (initial) .. T.  qvel: f[B, T+1, nv].
    ctrl: f[B, T, nu], control held during each tick.  time: f[T+1], seconds.
    finite: bool[B], the element stayed finite and in bounds for the whole horizon.
    first_bad: i32[B], first tick (1..T) whose state was bad, -1 if none.
    ncon: i32[B, T+1], contacts with penetration (dist < 0) at each tick, for diagnostics.
    pstate: the policy state after the last tick (pytree, leading axis B).
    backend: "c", "mjx" or "warp".
    """

    qpos: np.ndarray
    qvel: np.ndarray
    ctrl: np.ndarray
    time: np.ndarray
    finite: np.ndarray
    first_bad: np.ndarray
    ncon: np.ndarray
    pstate: Any
    backend: str


BACKENDS = ("c", "mjx", "warp")


def _has_gpu() -> bool:
    try:
        return bool(jax.devices("gpu"))
    except RuntimeError:
        return False


def warp_available() -> bool:
    """MJX's Warp implementation imports (``pip install 'jaxplan[warp]'``: warp-lang)."""
    try:
        import warp  # noqa: F401
    except ImportError:
        return False
    return True


def default_backend(model: mujoco.MjModel | None = None) -> str:
    """The engine measured fastest here (docs/physics.md, Engines): the C engine on a CPU (it beat
    MJX-JAX and MJX-Warp on every scene measured on one); on a GPU MJX-Warp when it is installed
    (built for contact-rich worlds), else MJX-JAX. ``model`` is accepted for the scene-size rule
    (none is needed by the measurements so far)."""
    if not _has_gpu():
        return "c"
    return "warp" if warp_available() else "mjx"


def schedule_policy(params, pstate, qpos, qvel, time):
    """Open-loop policy: ``params = (ctrl f[T, nu], tick_seconds f[])``; ignores the state."""
    table, tick = params
    i = jnp.clip(jnp.floor(time / tick + 1e-6).astype(jnp.int32), 0, table.shape[0] - 1)
    return table[i], pstate


def free_qpos_addresses(model: mujoco.MjModel) -> np.ndarray:
    """``i32[F]`` qpos address of every free joint (its body's x, y, z follow)."""
    free = np.nonzero(model.jnt_type == mujoco.mjtJoint.mjJNT_FREE)[0]
    return model.jnt_qposadr[free].astype(np.int32)


def _state_ok(qpos, qvel, free_adr, lo, hi, xp):
    """Element is finite and every free body's position lies in [lo, hi] (f[3] each)."""
    finite = xp.all(xp.isfinite(qpos), -1) & xp.all(xp.isfinite(qvel), -1)
    if free_adr.size == 0:
        return finite
    pos = xp.stack([qpos[..., free_adr + k] for k in range(3)], -1)    # [..., F, 3]
    inside = xp.all((pos >= lo) & (pos <= hi), axis=(-1, -2))
    return finite & inside


class Simulator:
    """Batched closed-loop rollouts of one model on a chosen engine.

    model: MjModel (its ``opt`` holds timestep, integrator, solver iterations).
    policy: the pure JAX policy above (must be hashable: a module-level function or a partial).
    substeps: physics steps per control tick.  bounds: ``(lo f[3], hi f[3])`` world box for free
      bodies (None: unbounded).  backend: "c" (MuJoCo C, threads), "mjx" (MJX-JAX), "warp" (MJX-Warp) or
      "auto" (:func:`default_backend`; the pick is logged and kept in ``backend``, ``auto`` is True).
    nthread: C-engine threads (default: all cores).
    mjx_model: the model MJX steps instead of ``model`` (same bodies, joints and actuators; e.g. only
      the contact pairs that can happen declared, ``PushWorld.mjx_model``). None: ``model``.
    compiler_options: XLA options for MJX's program (e.g. :data:`FAST_COMPILE`); None: XLA's defaults.

    ``run`` compiles once per (horizon, batch size) on MJX; later calls with new states, policy
    parameters or policy states reuse the compiled program. ``compile_seconds`` is what the last
    ``run`` (or ``compile``) spent tracing and compiling (0.0 when it reused a program, and always on
    the C engine); ``memory_bytes`` the last compiled program's buffers (``compile``).
    """

    def __init__(self, model: mujoco.MjModel, policy: Policy, *, substeps: int = 1, bounds=None,
                 backend: str = "auto", nthread: int | None = None, mjx_model: mujoco.MjModel | None = None,
                 compiler_options: dict | None = None):
        self.auto = backend == "auto"
        if backend == "auto":
            backend = default_backend(model)
            logging.getLogger(__name__).info("Simulator backend='auto' picked %r (GPU: %s, warp: %s)", backend,
                                             _has_gpu(), warp_available())
        if backend not in BACKENDS:
            raise ValueError(f"backend: expected 'c', 'mjx', 'warp' or 'auto'; got {backend!r}.")
        if backend == "warp" and not warp_available():
            raise ValueError("backend='warp': MJX's Warp implementation needs warp-lang; "
                             "pip install 'jaxplan[warp]' (warp-lang==1.18.0).")
        if int(substeps) < 1:
            raise ValueError(f"substeps: must be an int >= 1; got {substeps!r}.")
        if mjx_model is not None and (mjx_model.nq, mjx_model.nv, mjx_model.nu) != (model.nq, model.nv, model.nu):
            raise ValueError(f"mjx_model: expected nq, nv, nu = {(model.nq, model.nv, model.nu)} as model; got "
                             f"{(mjx_model.nq, mjx_model.nv, mjx_model.nu)}.")
        self.model = model
        self.mjx_model = model if mjx_model is None else mjx_model
        self.compiler_options = dict(compiler_options) if compiler_options else None
        self.policy = policy
        self.substeps = int(substeps)
        self.backend = backend
        self.free_adr = free_qpos_addresses(model)
        big = np.full(3, np.inf)
        self.lo, self.hi = (-big, big) if bounds is None else (np.asarray(bounds[0], float),
                                                                np.asarray(bounds[1], float))
        self.nthread = max(1, nthread or os.cpu_count() or 1)
        self._mjx_cache: dict = {}
        self._executables: dict = {}
        self.compile_seconds = 0.0
        self.memory_bytes: int | None = None
        self._policy_batch = jax.jit(jax.vmap(policy))

    # ------------------------------------------------------------------------------------ public
    def run(self, qpos0, qvel0, params, pstate0, n_ticks: int, model_fields=None) -> Trajectory:
        """Roll out B elements for ``n_ticks`` control ticks. qpos0 f[B, nq], qvel0 f[B, nv];
        params, pstate0: policy pytrees with leading axis B. model_fields: optional
        ``{name: f[B, *shape]}``, per-element values of ``MjModel`` fields (``shape`` = the field's)."""
        qpos0, qvel0, n_ticks, fields = self._checked(qpos0, qvel0, n_ticks, model_fields)
        run = self._run_c if self.backend == "c" else self._run_mjx
        return run(qpos0, qvel0, params, pstate0, n_ticks, fields)

    def compile(self, qpos0, qvel0, params, pstate0, n_ticks: int, model_fields=None) -> float:
        """Trace and compile the program ``run`` would run on these inputs, without running it (MJX-JAX
        and MJX-Warp; the C engine has nothing to compile). Returns ``compile_seconds`` (0.0 when the
        program was already compiled); ``memory_bytes`` then holds the program's buffers as XLA
        sizes them (arguments, outputs and temporaries; None where XLA does not say)."""
        qpos0, qvel0, n_ticks, fields = self._checked(qpos0, qvel0, n_ticks, model_fields)
        if self.backend != "c":
            self._executable(self._mjx_args(qpos0, qvel0, params, pstate0, fields), n_ticks, tuple(sorted(fields)))
        else:
            self.compile_seconds = 0.0
        return self.compile_seconds

    def _checked(self, qpos0, qvel0, n_ticks, model_fields):
        qpos0 = np.asarray(qpos0, np.float64)
        qvel0 = np.asarray(qvel0, np.float64)
        if qpos0.ndim != 2 or qpos0.shape[1] != self.model.nq:
            raise ValueError(f"qpos0: expected shape [B, {self.model.nq}]; got {qpos0.shape}.")
        if qvel0.shape != (qpos0.shape[0], self.model.nv):
            raise ValueError(f"qvel0: expected shape [{qpos0.shape[0]}, {self.model.nv}]; got {qvel0.shape}.")
        if int(n_ticks) < 1:
            raise ValueError(f"n_ticks: must be >= 1; got {n_ticks!r}.")
        fields = self._check_fields(model_fields, qpos0.shape[0])
        if fields and self.backend == "warp" and self.auto:
            logging.getLogger(__name__).info("Simulator backend='auto': model_fields need MJX-JAX; using 'mjx'")
            self.backend = "mjx"
        if fields and self.backend == "warp":
            raise ValueError("model_fields: per-element model fields are not supported on backend='warp'; "
                             "use 'mjx' or 'c'.")
        return qpos0, qvel0, int(n_ticks), fields

    @property
    def tick_seconds(self) -> float:
        return float(self.model.opt.timestep) * self.substeps

    def _check_fields(self, model_fields, b: int) -> dict:
        fields = {}
        for name, value in (model_fields or {}).items():
            base = getattr(self.model, name, None)
            if not isinstance(base, np.ndarray) or base.dtype.kind not in "fiu":
                raise ValueError(f"model_fields[{name!r}]: not a numeric MjModel array field.")
            value = np.asarray(value, np.float64)
            if value.shape != (b,) + base.shape:
                raise ValueError(f"model_fields[{name!r}]: expected shape {(b,) + base.shape} (batch, then the "
                                 f"field's own shape); got {value.shape}.")
            if not np.all(np.isfinite(value)):
                raise ValueError(f"model_fields[{name!r}]: values must be finite.")
            fields[name] = value.astype(base.dtype)
        return fields

    # ------------------------------------------------------------------------------------ MJX
    def _mjx_fn(self, n_ticks: int, field_names: tuple = ()):
        key = (n_ticks, field_names)
        if key in self._mjx_cache:
            return self._mjx_cache[key]
        from mujoco import mjx

        warp = self.backend == "warp"
        if warp:
            mx = mjx.put_model(self.mjx_model, impl="warp")
            d0 = mjx.make_data(self.mjx_model, impl="warp")
        else:
            mx = mjx.put_model(self.mjx_model)
            d0 = mjx.make_data(mx)
        missing = [k for k in field_names if not hasattr(mx, k)]
        if missing:
            raise ValueError(f"model_fields: MJX's model has no field {missing[0]!r}; use the C engine for it.")
        policy, substeps = self.policy, self.substeps
        free_adr = jnp.asarray(self.free_adr)
        lo, hi = jnp.asarray(self.lo, jnp.float32), jnp.asarray(self.hi, jnp.float32)

        def ncon_of(d):
            if warp:   # counted on the host afterwards
                return jnp.int32(0)
            return jnp.sum(d._impl.contact.dist < 0).astype(jnp.int32) if d._impl.contact.dist.size else jnp.int32(0)

        def single(qpos0, qvel0, params, pstate0, fields):
            m = mx.replace(**{k: v.astype(getattr(mx, k).dtype) for k, v in fields.items()}) if fields else mx
            # No mjx.forward here: the policy reads only qpos / qvel / time, and every mjx.step starts
            # with its own forward pass; one copy of the collision code keeps the compile small.
            d = d0.replace(qpos=qpos0.astype(d0.qpos.dtype), qvel=qvel0.astype(d0.qvel.dtype))

            def tick(carry, t):
                d, ps, ok, first_bad = carry
                ctrl, ps = policy(params, ps, d.qpos, d.qvel, d.time)
                d = d.replace(ctrl=ctrl.astype(d.ctrl.dtype))
                d = jax.lax.fori_loop(0, substeps, lambda _, dd: mjx.step(m, dd), d)
                good = _state_ok(d.qpos, d.qvel, free_adr, lo, hi, jnp)
                first_bad = jnp.where(ok & ~good, t + 1, first_bad)
                return (d, ps, ok & good, first_bad), (d.qpos, d.qvel, ctrl, ncon_of(d))

            init = (d, pstate0, jnp.bool_(True), jnp.int32(-1))
            (d, ps, ok, first_bad), (qp, qv, ctrl, ncon) = jax.lax.scan(tick, init, jnp.arange(n_ticks))
            qp = jnp.concatenate([qpos0[None].astype(qp.dtype), qp])
            qv = jnp.concatenate([qvel0[None].astype(qv.dtype), qv])
            return qp, qv, ctrl, ok, first_bad, ncon, ps

        fn = jax.jit(jax.vmap(single), compiler_options=self.compiler_options)
        self._mjx_cache[key] = fn
        return fn

    @staticmethod
    def _mjx_args(qpos0, qvel0, params, pstate0, fields) -> tuple:
        fields = {k: jnp.asarray(v) for k, v in fields.items()}
        return jnp.asarray(qpos0, jnp.float32), jnp.asarray(qvel0, jnp.float32), params, pstate0, fields

    def _executable(self, args: tuple, n_ticks: int, names: tuple):
        """The compiled program for ``args`` (compiled ahead of the call so that its cost is measured
        apart: ``compile_seconds``, ``memory_bytes``)."""
        key = (n_ticks, names, jax.tree_util.tree_structure(args),
               tuple((np.shape(x), str(jnp.result_type(x))) for x in jax.tree_util.tree_leaves(args)))
        self.compile_seconds = 0.0
        if key not in self._executables:
            start = time.perf_counter()
            self._executables[key] = self._mjx_fn(n_ticks, names).lower(*args).compile()
            self.compile_seconds = time.perf_counter() - start
            self.memory_bytes = _program_bytes(self._executables[key])
        return self._executables[key]

    def _run_mjx(self, qpos0, qvel0, params, pstate0, n_ticks, fields):
        args = self._mjx_args(qpos0, qvel0, params, pstate0, fields)
        executable = self._executable(args, n_ticks, tuple(sorted(fields)))
        qp, qv, ctrl, ok, first_bad, ncon, ps = jax.block_until_ready(executable(*args))
        tick_times = np.arange(n_ticks + 1) * self.tick_seconds
        # Contacts at tick 0 (every tick on Warp) from the C engine on the MJX model: a second MJX
        # collision pass would double the compiled program for a diagnostic.
        qp = np.asarray(qp)
        ncon = np.asarray(ncon)
        ticks = range(qp.shape[1]) if self.backend == "warp" else range(1)
        host = _host_ncon(self.mjx_model, qp[:, list(ticks)])
        ncon = host if self.backend == "warp" else np.concatenate([host, ncon], 1)
        return Trajectory(qp, np.asarray(qv), np.asarray(ctrl), tick_times, np.asarray(ok),
                          np.asarray(first_bad), ncon.astype(np.int32), ps, self.backend)

    # ------------------------------------------------------------------------------------ C engine
    def _c_model(self) -> mujoco.MjModel:
        model = _copy_model(self.model)   # a copy: the caller's model keeps its flags
        model.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_AUTORESET)
        return model

    def _run_c(self, qpos0, qvel0, params, pstate0, n_ticks, fields):
        model = self._c_model()
        b = qpos0.shape[0]
        models = [_with_fields(model, {k: v[i] for k, v in fields.items()}) for i in range(b)] if fields \
            else [model] * b
        datas = [mujoco.MjData(m) for m in models]
        for i, d in enumerate(datas):
            d.qpos[:], d.qvel[:] = qpos0[i], qvel0[i]
            mujoco.mj_forward(models[i], d)
        qp = np.empty((b, n_ticks + 1, model.nq))
        qv = np.empty((b, n_ticks + 1, model.nv))
        ctrl_out = np.zeros((b, n_ticks, model.nu))
        ncon = np.zeros((b, n_ticks + 1), np.int32)
        qp[:, 0], qv[:, 0] = qpos0, qvel0
        ncon[:, 0] = [_active_contacts(d) for d in datas]
        ok = np.ones(b, bool)
        first_bad = np.full(b, -1, np.int32)
        pstate = pstate0
        substeps = self.substeps

        def advance(i, ctrl_i):
            d = datas[i]
            d.ctrl[:] = ctrl_i
            with np.errstate(all="ignore"):
                mujoco.mj_step(models[i], d, nstep=substeps)
            return i

        with concurrent.futures.ThreadPoolExecutor(self.nthread) as pool:
            for t in range(n_ticks):
                times = np.array([d.time for d in datas])
                ctrl, pstate = self._policy_batch(params, pstate, jnp.asarray(qp[:, t], jnp.float32),
                                                  jnp.asarray(qv[:, t], jnp.float32), jnp.asarray(times, jnp.float32))
                ctrl = np.asarray(ctrl, np.float64)
                live = np.nonzero(ok)[0]
                list(pool.map(lambda i: advance(i, ctrl[i]), live))
                for i in range(b):
                    if ok[i]:
                        qp[i, t + 1], qv[i, t + 1] = datas[i].qpos, datas[i].qvel
                        ncon[i, t + 1] = _active_contacts(datas[i])
                    else:  # frozen: repeat the last state
                        qp[i, t + 1], qv[i, t + 1], ncon[i, t + 1] = qp[i, t], qv[i, t], ncon[i, t]
                ctrl_out[:, t] = np.where(ok[:, None], ctrl, 0.0)
                good = _state_ok(qp[:, t + 1], qv[:, t + 1], self.free_adr, self.lo, self.hi, np)
                newly = ok & ~good
                first_bad[newly] = t + 1
                ok &= good
        tick_times = np.arange(n_ticks + 1) * self.tick_seconds
        return Trajectory(qp, qv, ctrl_out, tick_times, ok, first_bad, ncon, pstate, "c")


def _program_bytes(executable) -> int | None:
    """Arguments + outputs + temporaries of a compiled XLA program, in bytes (None if unknown)."""
    try:
        m = executable.memory_analysis()
        return int(m.argument_size_in_bytes + m.output_size_in_bytes + m.temp_size_in_bytes)
    except (AttributeError, NotImplementedError, TypeError):
        return None


def _host_ncon(model: mujoco.MjModel, qpos) -> np.ndarray:
    """i32[B, K] penetrating contacts of ``model`` at the states ``qpos f[B, K, nq]`` (C engine)."""
    d = mujoco.MjData(model)
    out = np.zeros(qpos.shape[:2], np.int32)
    for i in range(qpos.shape[0]):
        for k in range(qpos.shape[1]):
            if np.all(np.isfinite(qpos[i, k])):
                d.qpos[:] = qpos[i, k]
                mujoco.mj_forward(model, d)
                out[i, k] = _active_contacts(d)
    return out


def _active_contacts(d: mujoco.MjData) -> int:
    return int(np.sum(d.contact.dist[: d.ncon] < 0)) if d.ncon else 0


def _with_fields(model: mujoco.MjModel, values: dict) -> mujoco.MjModel:
    """A copy of ``model`` with the given array fields overwritten (the C engine's per-element model)."""
    copy = _copy_model(model)
    for name, value in values.items():
        getattr(copy, name)[...] = value
    return copy


def _copy_model(model: mujoco.MjModel) -> mujoco.MjModel:
    import copy

    return copy.copy(model)
