"""Wall-clock timing of JAX calls (JAX dispatches asynchronously: wait for the outputs first)."""
from __future__ import annotations

import time

import jax


def timed(fn, *args):
    """``(result, milliseconds)`` of one call ``fn(*args)``, waiting for every output array."""
    start = time.perf_counter()
    out = jax.block_until_ready(fn(*args))
    return out, (time.perf_counter() - start) * 1e3
