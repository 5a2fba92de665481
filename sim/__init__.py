"""Batched quadrotor simulator (thesis §3.3.1): arrays in, arrays out.

It knows nothing of goals, datasets or learning.
"""
