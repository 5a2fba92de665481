"""Informative path planning on motion primitives (thesis chapter 2)."""
