"""Physics: one batched rollout interface (``rollout.Simulator``) over MuJoCo's C engine and MJX,
shared by the transport rover and PushAround. See docs/physics.md."""
from jaxplan.physics.rollout import Simulator, Trajectory, default_backend

__all__ = ["Simulator", "Trajectory", "default_backend"]
