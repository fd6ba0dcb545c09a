"""The Ray backend of jaxplan.sweep on a local Ray instance (loopback): same rows as the local
backend, and a chunk task that fails once is retried."""
from __future__ import annotations

import pytest

ray = pytest.importorskip("ray", reason="the Ray backend needs the extra jaxplan[distributed]")

from jaxplan import sweep  # noqa: E402

# One random 6x6 scene x 2 angles x 3 thresholds = 6 settings; one angle (3 settings) per chunk: 2 Ray tasks.
SPEC = {"random_scenes": {"seeds": [7], "shape": [6, 6], "density": 0.7},
        "fabric": {"theta_tol_deg": [45.0, 60.0], "tau_h": [0.2, 0.4, 0.6]},
        "spill": {"lam": 0.1},
        "metrics": {"top_sources": 2}}


@pytest.fixture(scope="module")
def local_ray():
    # one CPU: one worker process, so the chunk kernel compiles once there
    ray.init(num_cpus=1, include_dashboard=False, log_to_driver=False, configure_logging=False)
    yield
    ray.shutdown()


@pytest.fixture(scope="module")
def budget():
    return sweep.bytes_per_table(sweep.load_spec(SPEC).scenes[0][1], per_table=3) / 2**20   # one theta per chunk


def test_ray_backend_retries_and_matches_local(tmp_path, local_ray, budget):
    marker = tmp_path / "failed-once"
    ray_out = sweep.run_sweep(SPEC, tmp_path / "ray.csv", backend="ray", memory_budget_mb=budget,
                              progress=False, max_retries=2, _fault_marker=str(marker))
    assert marker.exists()   # one task attempt raised, and Ray's retry recovered it
    local_out = sweep.run_sweep(SPEC, tmp_path / "local.csv", memory_budget_mb=budget, progress=False)
    text = ray_out.read_text()
    assert text == local_out.read_text()
    assert len(text.splitlines()) == 1 + 6


def test_ray_backend_resumes_a_partial_file(tmp_path, local_ray, budget):
    full = sweep.run_sweep(SPEC, tmp_path / "full.csv", memory_budget_mb=budget, progress=False).read_text()
    out = tmp_path / "partial.csv"
    out.write_text("".join(full.splitlines(keepends=True)[:3]))
    sweep.run_sweep(SPEC, out, backend="ray", memory_budget_mb=budget, progress=False)
    assert out.read_text() == full


def test_ray_failing_every_attempt_raises(tmp_path, local_ray, budget):
    # no retries: the injected failure of the first attempt reaches the caller, and the rows written
    # before it stay for a resume
    with pytest.raises(Exception, match="injected failure"):
        sweep.run_sweep(SPEC, tmp_path / "fail.csv", backend="ray", memory_budget_mb=budget, progress=False,
                        max_retries=0, _fault_marker=str(tmp_path / "m"))
