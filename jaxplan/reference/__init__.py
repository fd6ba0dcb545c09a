"""Plain serial reference implementations that the JAX kernels are tested against.

``reference_fabric`` (Sections 3.1-3.4 of the paper) is plain Python + numpy, no JAX: the oracle for
property tests and the peer that benchmarks compare against. See docs/transport.md.
"""
from jaxplan.reference.fabric import ReferenceFabric, reference_fabric

__all__ = ["ReferenceFabric", "reference_fabric"]
