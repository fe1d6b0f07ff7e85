"""Designs shared by the statistics tests.

- ``helmert``: 4-parameter 2-D Helmert transformation of the nine left-image points of paper 000
  (Table 3), right image observed with correlated x/y per point (a different 2×2 covariance per
  point), so P is a full (block-diagonal) matrix and Qvv has strongly uneven entries.
- ``poly``: cubic regression at uneven abscissae (one far point with high leverage) with AR(1)
  correlated observations (a full, non-block P).
"""


import pytest
from .stats_helpers import helmert_model, poly_model


@pytest.fixture(scope="session")
def helmert():
    return helmert_model()


@pytest.fixture(scope="session")
def poly():
    return poly_model()
