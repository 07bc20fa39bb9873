"""The law's own metric (docs/design.md §2.5.1): Q = K + lam Kp, V = d^2/2 a Lyapunov function."""
import numpy as np
import pytest

from fmu_sync.core import energy_metric
from fmu_sync.core.coupling import laplacian_factor
from fmu_sync.core.network import all_to_all, path, ring, star


def test_energy_metric_pair_and_errors():
    np.testing.assert_array_equal(energy_metric(1.0, 3.0), [[7.0]])
    K = np.array([[2.0, -1.0], [-1.0, 2.0]])
    Kp = np.array([[1.0, 0.5], [0.5, 3.0]])
    np.testing.assert_allclose(energy_metric(K, Kp), K + 2 * Kp)
    # non-identical systems: the mean stiffness
    np.testing.assert_allclose(energy_metric([1.0, 3.0], 0.5), [[3.0]])
    # negative stiffness outweighed by the gain: fine; not outweighed / K = Kp = 0: a clear error
    np.testing.assert_allclose(energy_metric(-1.0, 1.0), [[1.0]])
    for K_, Kp_ in ((0.0, 0.0), (-3.0, 1.0)):
        with pytest.raises(ValueError, match="not positive definite"):
            energy_metric(K_, Kp_)


def test_laplacian_factor_exact_only_when_L2_proportional_to_L():
    for A in (None, all_to_all(5, 0.3), [[0, 2.0], [2.0, 0]]):
        lam, exact = laplacian_factor(A)
        assert exact
        if A is not None:
            a = np.asarray(A, float)
            L = np.diag(a.sum(1)) - a
            np.testing.assert_allclose(L @ L, lam * L, atol=1e-12)
    assert laplacian_factor(None)[0] == 2.0
    assert laplacian_factor(all_to_all(5, 0.3))[0] == pytest.approx(1.5)
    for A in (ring(8), path(4), star(5)):
        lam, exact = laplacian_factor(A)
        a = np.asarray(A, float)
        L = np.diag(a.sum(1)) - a
        assert not exact and not np.allclose(L @ L, lam * L)
        assert lam == pytest.approx(np.trace(L) / (len(a) - 1))
