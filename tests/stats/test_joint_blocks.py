"""GroupBlocks: the array-backed mapping of 2 × 2 ``P Qvv P`` blocks behaves as the dict it replaces,
and the joint 2-D test gives the same statistics with either."""

import numpy as np
import pytest

from baarda.pipeline.stats import GroupBlocks, Snapshot, joint_test_2d


def _blocks(rng, m):
    A = rng.standard_normal((m, 2, 2))
    return A @ np.swapaxes(A, 1, 2) + 0.5 * np.eye(2)


def test_mapping_like_a_dict():
    rng = np.random.default_rng(3)
    ids = rng.permutation(np.arange(0, 40, 2))               # unsorted, with gaps
    B = _blocks(rng, ids.size)
    d = {int(g): B[k] for k, g in enumerate(ids)}
    gb = GroupBlocks(ids, B)
    assert len(gb) == len(d) and set(gb) == set(d)
    for g in d:
        assert g in gb and np.array_equal(gb[g], d[g])
    assert 1 not in gb and 41 not in gb and -2 not in gb and "x" not in gb
    with pytest.raises(KeyError):
        gb[3]
    np.testing.assert_array_equal(gb.take([4, 0, 38]), np.stack([d[4], d[0], d[38]]))
    np.testing.assert_array_equal(gb.has([4, 5, 38, 100]), [True, False, True, False])
    with pytest.raises(KeyError, match="5"):
        gb.take([4, 5])
    assert dict(gb.items()).keys() == d.keys()
    assert GroupBlocks.of(d).take([2]).tolist() == [d[2].tolist()]
    assert len(GroupBlocks.of(None)) == 0 and not GroupBlocks.of({}).has([0]).any()
    with pytest.raises(ValueError, match="repeated"):
        GroupBlocks([1, 1], B[:2])
    assert not gb.blocks.flags.writeable


def test_joint_test_same_with_dict_and_arrays():
    rng = np.random.default_rng(4)
    m = 50
    B = _blocks(rng, m)
    Pv = rng.standard_normal(2 * m)
    group = np.repeat(np.arange(m), 2)
    common = dict(v=Pv, Pv=Pv, PQvvP=np.ones(2 * m), r=np.full(2 * m, 0.5), sigma_l=np.ones(2 * m),
                  vtpv=float(Pv @ Pv), dof=m, group=group)
    a = joint_test_2d(Snapshot(**common, PQvvP_blocks={g: B[g] for g in range(m)}))
    b = joint_test_2d(Snapshot(**common, PQvvP_blocks=GroupBlocks(np.arange(m), B)))
    np.testing.assert_array_equal(a.T, b.T)
    np.testing.assert_array_equal(a.flagged, b.flagged)
    # the statistic by its closed form for one group: gᵀ B⁻¹ g / σ0²
    g0 = Pv[:2]
    assert a.T[0] == pytest.approx(g0 @ np.linalg.solve(B[0], g0), rel=1e-12)
    with pytest.raises(ValueError, match="PQvvP_blocks"):
        joint_test_2d(Snapshot(**common, PQvvP_blocks=GroupBlocks(np.arange(m - 1), B[:-1])))
