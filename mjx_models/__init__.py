"""MJCF models shipped with jaxplan (``rover.xml``: the shovel rover of the transport system).

A package only so that the files travel inside the wheel; read them through ``MODEL_DIR``.
"""
from pathlib import Path

MODEL_DIR = Path(__file__).resolve().parent

__all__ = ["MODEL_DIR"]
