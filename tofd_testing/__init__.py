"""Support shared by the tests (tests/) and the benchmarks (bench/): rendered frame sources, a test config and
model, damaged recordings, helpers that run and probe `tofd` processes. Part of the source checkout, not of the
installed package (the benchmarks and tests run from a checkout)."""

HANG_GUARD_S = 120
"""Seconds a test waits for a tofd process or line: a hang fails the test instead of blocking the suite; not a speed
bound."""
