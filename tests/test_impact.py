"""The impact map Z (docs/design.md §2.2) against its defining properties."""
import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from fmu_sync.core import ImpactOscillator, MechanicalSystem, impact_map

M = np.array([[2.0, 0.5], [0.5, 1.0]])
w = np.array([1.0, -0.5])
g0 = 0.3


def two_dof(e):
    z = np.zeros((2, 2))
    return MechanicalSystem(M=M, K=z, C=z, f0=[0, 0], w=w, g0=g0, e=e)


def on_wall(t):
    # a point of the hyperplane w^T q + g0 = 0
    return -g0 * w / (w @ w) + t * np.array([w[1], -w[0]])


def test_one_dof_newton_law():
    s = ImpactOscillator(m=3.0, e=0.8)
    assert impact_map(s, 0.0, -2.0) == pytest.approx(1.6, abs=1e-15)
    assert impact_map(s, 0.0, 1.5) == 1.5           # leaving: fixed point
    with pytest.raises(ValueError, match=r"g\(q\) = 0 only; got g\(q\) = 0.1"):
        impact_map(s, 0.1, -1.0)


vec = st.lists(st.floats(-10, 10), min_size=2, max_size=2).map(np.array)


@settings(max_examples=200, deadline=None)
@given(u=vec, v=vec, t=st.floats(-2, 2), e=st.sampled_from([0.0, 0.05, 0.8, 1.0]))
def test_newton_law_fixed_points_and_non_expansive(u, v, t, e):
    s = two_dof(e)
    q = on_wall(t)
    zu, zv = impact_map(s, q, u), impact_map(s, q, v)
    wu = w @ u
    # Newton's law along w, tangential (M-orthogonal) part kept
    expected_wz = -e * wu if wu < 0 else wu
    assert w @ zu == pytest.approx(expected_wz, abs=1e-12 * (1 + abs(wu)))
    # post-impact states are fixed points: Z o Z = Z
    np.testing.assert_allclose(impact_map(s, q, zu), zu, atol=1e-12 * (1 + np.abs(u).max()))
    # non-expansive in the M-norm
    d = zu - zv
    assert d @ M @ d <= (u - v) @ M @ (u - v) * (1 + 1e-12) + 1e-20
