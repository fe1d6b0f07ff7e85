"""The ``metashape`` AP model: its Jacobians against central differences; registered by name."""

import numpy as np

from baarda.pipeline.camera.metashape_model import MetashapeAP
from baarda.pipeline.camera.models import APModel


def test_jacobians_match_finite_differences():
    rng = np.random.default_rng(3)
    n = 50
    x, y = rng.uniform(-6, 6, n), rng.uniform(-4, 4, n)
    q = np.array([[-2e-3, 1e-5, -3e-8, 2e-10, 3e-5, -2e-5, 4e-3, -1e-4, 5e-4, -3e-4]] * n)
    m = MetashapeAP()
    fd = APModel.jacobian_params.__get__(m)(x, y, q, np.full(n, 8.0), None)
    np.testing.assert_allclose(m.jacobian_params(x, y, q, 8.0, None), fd, rtol=1e-6, atol=1e-9)
    fd_xy = APModel.jacobian_xy.__get__(m)(x, y, q, np.full(n, 8.0), None)
    np.testing.assert_allclose(m.jacobian_xy(x, y, q, 8.0, None), fd_xy, rtol=1e-6, atol=1e-8)


def test_registered():
    from baarda.pipeline.camera.registry import get_ap_model

    assert get_ap_model("metashape").params[3] == "K4"
