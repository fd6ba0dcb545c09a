"""Physics: one batched rollout interface (MJX and the C engine), the shovel rover and its world
built from a Scene, and the 3D <-> 2D bridge that checks planned routes. See docs/physics.md."""
