"""Physics: one batched rollout interface (``rollout.Simulator``) over MuJoCo's C engine and MJX,
shared by the transport rover and PushAround. See docs/physics.md."""
from jaxplan.physics.rollout import FAST_COMPILE, Simulator, Trajectory, default_backend, warp_available

__all__ = ["FAST_COMPILE", "Simulator", "Trajectory", "default_backend", "warp_available"]
