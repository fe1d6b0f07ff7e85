"""Seeded synthetic scenes — blocks with their truth — for tests, benchmarks, the cross-check and
the simulated test field.  Pure numerics: randomness only through ``rng`` / ``seed`` arguments, no
files, no rerun.

* :mod:`.aerial` — digital-camera blocks: convergent close range and aerial strips of any size
  (:func:`~.aerial.simulate_convergent`, :func:`~.aerial.simulate_aerial`, :func:`~.aerial.perturb_start`);
* :mod:`.closerange` — a small convergent block with a camera of any built-in AP model;
* :mod:`.normalcase` — a small normal-case strip block for the independent models;
* :mod:`.testfield` — paper 001's test field (P31 camera, control cases, systematic errors).
"""
