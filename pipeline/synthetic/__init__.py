"""Seeded synthetic scenes (blocks with their truth) for tests, benchmarks, the cross-check and the
simulated test field.  Randomness only through an ``rng`` argument."""
