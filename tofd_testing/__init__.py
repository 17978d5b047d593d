"""Support shared by the tests (tests/) and the benchmarks (bench/): rendered frame sources, a test config and
model, damaged recordings, helpers that run and probe `tofd` processes. Part of the source checkout, not of the
installed package (the benchmarks and tests run from a checkout)."""
