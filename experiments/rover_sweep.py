"""Sweep of the rover's physics parameters in one batched rollout.

One route (the first by J of ``--scene``) is rolled out once per (friction, speed) pair, all pairs
in one ``bridge.check_routes`` call: the batch axis carries the route repeated, a sliding friction
per element (``friction=``, per-element ``geom_friction`` through ``Simulator.run``'s
``model_fields``) and a blade speed per element (``speed=``, a policy parameter). ``check_routes``
seeds each element's particle jitter by its batch index, so differences between elements include
layout noise (``bench_rover.py`` measures it: CV 0.02 on the default scene's first route).

Reported per pair: delivered / spilled / left-behind objects, mean and max lateral error (cells),
time to the stop (s), reached, finite; and the wall time of the whole batch. Results:
``experiments/results/rover_sweep.{json,md}``.

Examples::

    python -m experiments.rover_sweep                       # default scene, C engine
    python -m experiments.rover_sweep --backend mjx         # on a GPU (the device tool)
"""
from __future__ import annotations

import argparse
import datetime as _dt
import itertools
import json
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np

from jaxplan.transport import BUILTIN_SCENES

RESULTS_DIR = Path(__file__).resolve().parent / "results"


def _floats(text):
    try:
        values = [float(v) for v in text.split(",")]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated numbers; got {text!r}") from None
    if not values or not all(np.isfinite(v) and v > 0 for v in values):
        raise argparse.ArgumentTypeError(f"expected positive numbers; got {text!r}")
    return values


def main(argv=None):
    ap = argparse.ArgumentParser(prog="python -m experiments.rover_sweep", description=__doc__.split("\n")[0])
    ap.add_argument("--scene", default="default", choices=BUILTIN_SCENES, help="built-in scene (default: default)")
    ap.add_argument("--frictions", type=_floats, default=[0.3, 0.6, 0.9], help="sliding frictions, e.g. 0.3,0.6,0.9")
    ap.add_argument("--speeds", type=_floats, default=[0.5, 0.8, 1.2], help="blade speeds in cells/s, e.g. 0.5,0.8")
    ap.add_argument("--backend", default="c", choices=("c", "mjx", "auto"), help="physics engine (default c)")
    args = ap.parse_args(argv)

    import jax

    from jaxplan import builtin_scene
    from jaxplan.transport.physics import check_routes, plan_routes

    scene = builtin_scene(args.scene)
    _, routes, sources = plan_routes(scene, n_routes=1)
    pairs = list(itertools.product(args.frictions, args.speeds))
    batch = jax.tree.map(lambda a: np.repeat(np.asarray(a)[:1], len(pairs), 0), routes)
    friction = np.array([f for f, _ in pairs])
    speed = np.array([v for _, v in pairs])
    print(f"{scene.name or args.scene}: route from {tuple(int(v) for v in sources[0])}, "
          f"{len(pairs)} (friction, speed) pairs in one batch on {args.backend} ...", flush=True)
    t0 = time.perf_counter()
    chk = check_routes(scene, batch, backend=args.backend, friction=friction, speed=speed)
    wall = time.perf_counter() - t0
    rows = []
    for (f, v), row in zip(pairs, chk.outcome.rows()):
        rows.append(dict(row, friction=f, speed=v))
    result = {
        "date": _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds"),
        "host": {"platform": platform.platform(), "python": sys.version.split()[0], "cpus": os.cpu_count(),
                 "jax": jax.__version__, "jax_devices": [str(d) for d in jax.devices()],
                 "mujoco": __import__("mujoco").__version__},
        "scene": scene.name or args.scene, "source": [int(v) for v in sources[0]],
        "backend": chk.trajectory.backend, "ticks": chk.n_ticks, "particle_bodies": chk.world.n_particles,
        "wall_s": wall, "rows": rows,
    }
    md = to_markdown(result)
    print(md)
    RESULTS_DIR.mkdir(parents=True, exist_ok=True)
    (RESULTS_DIR / "rover_sweep.json").write_text(json.dumps(result, indent=1))
    (RESULTS_DIR / "rover_sweep.md").write_text(md)
    return 0


def to_markdown(r):
    L = ["# Rover parameter sweep (friction x speed, one batch)", "",
         f"{r['date']}, {r['host']['platform']}, {r['host']['cpus']} CPUs, jax {r['host']['jax']}, "
         f"mujoco {r['host']['mujoco']}, devices {r['host']['jax_devices']}.", "",
         f"Scene `{r['scene']}`, route from {tuple(r['source'])}, engine {r['backend']}, {len(r['rows'])} elements x "
         f"{r['ticks']} ticks, {r['particle_bodies']} particle bodies: {r['wall_s']:.1f} s for the batch. Each "
         "element has its own particle layout (jitter seeded by batch index).", "",
         "| friction | speed (cell/s) | collected | delivered | spilled | left behind | lost | mean lat (cell) "
         "| max lat (cell) | time (s) | reached | finite |",
         "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for x in r["rows"]:
        L.append(f"| {x['friction']:g} | {x['speed']:g} | {x['collected']:.0f} | {x['delivered']:.0f} "
                 f"| {x['spilled']:.0f} "
                 f"| {x['left_behind']:.0f} | {x['lost']:.0f} | {x['mean_lateral']:.3f} | {x['max_lateral']:.3f} "
                 f"| {x['time']:.1f} | {x['reached']} | {x['finite']} |")
    return "\n".join(L) + "\n"


if __name__ == "__main__":
    sys.exit(main())
