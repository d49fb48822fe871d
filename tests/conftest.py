"""Shared test fixtures: small model problems with known behaviour.

No global JAX configuration is changed here: jaxanm's entry points must keep float64 on
their own (tests/test_core.py checks it).
"""
