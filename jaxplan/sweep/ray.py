"""The Ray backend of ``jaxplan.sweep``: one Ray task per chunk, retried when it fails.

Ray is the optional extra ``jaxplan[distributed]`` and is imported only here, lazily. Each task calls
``sweep.evaluate_chunk`` (the same vmapped kernel as the local backend, compiled once per worker
process and grid shape), so the rows are identical to a local run.
"""
from __future__ import annotations

import os
from pathlib import Path


def _import_ray():
    try:
        import ray
    except ImportError:
        raise ValueError("backend: 'ray' needs Ray, which is not installed; install the extra with "
                         "pip install 'jaxplan[distributed]' (or use backend='local').") from None
    return ray


def _chunk_task(chunk, fault_marker):
    """Body of a Ray task. ``fault_marker`` (tests only): the first task to find no file there creates
    it and raises, so exactly one attempt fails and Ray's retry must recover."""
    if fault_marker is not None:
        try:
            fd = os.open(fault_marker, os.O_CREAT | os.O_EXCL | os.O_WRONLY)
        except FileExistsError:
            pass
        else:
            os.close(fd)
            raise RuntimeError(f"injected failure (marker {fault_marker})")
    from jaxplan.sweep import evaluate_chunk

    return evaluate_chunk(chunk)


def evaluate_chunks(chunks, *, address=None, max_retries: int = 3, fault_marker=None, window: int | None = None):
    """Yield ``evaluate_chunk(c)`` for each of ``chunks`` in order, computed by Ray tasks.

    address: a running cluster (``ray://...`` or ``host:port``); None = the Ray already initialised in
    this process, else a new local instance (shut down when done). At most ``window`` tasks are in
    flight (default 2 x the cluster's CPUs), so results stream back as the file is written.
    """
    ray = _import_ray()
    if isinstance(max_retries, bool) or not isinstance(max_retries, int) or max_retries < 0:
        raise ValueError(f"max_retries: must be an int >= 0; got {max_retries!r}.")
    started = False
    if address is not None:
        if not ray.is_initialized():
            ray.init(address=address, include_dashboard=False, log_to_driver=False)
            started = True
    elif not ray.is_initialized():
        ray.init(include_dashboard=False, log_to_driver=False)
        started = True
    try:
        task = ray.remote(max_retries=max_retries, retry_exceptions=True)(_chunk_task)
        marker = None if fault_marker is None else str(Path(fault_marker).resolve())
        window = window or max(2, 2 * int(ray.cluster_resources().get("CPU", 1)))
        chunks = list(chunks)
        refs = [task.remote(c, marker) for c in chunks[:window]]
        for i in range(len(chunks)):
            if i + window < len(chunks):
                refs.append(task.remote(chunks[i + window], marker))
            yield ray.get(refs[i])
            refs[i] = None
    finally:
        if started:
            ray.shutdown()
