"""Collision geometry: exact distance primitives, hand cases for every backend, and the
numpy-vs-fcl cross-check on thousands of random configurations.

Tolerance band of the cross-check: configurations whose exact clearance (numpy
``clearance``: distance minus radius, or minus 2r for self-collision, or the wall margin) satisfies
``|clearance| < 1e-6`` are skipped -- fcl decides such near-contacts with its own tolerances.
Everything else must agree exactly.
"""

from __future__ import annotations

import numpy as np
import pytest

from firmtool.errors import InputError
from firmtool.geometry import (
    CollisionBackend,
    FclCollisionBackend,
    NumpyCollisionBackend,
    make_backend,
    nonadjacent_pairs,
    segment_rectangle_distance,
    segment_segment_distance,
)
from firmtool.models.planar_arm import link_segments

BAND = 1e-6
BACKENDS = ["numpy", "fcl", "numba"]

UNIT = dict(obstacle_centers=np.zeros((1, 2)), obstacle_half_sizes=np.ones((1, 2)))
LO, HI = np.array([-5.0, -5.0]), np.array([5.0, 5.0])


def _backend(name, centers=None, halves=None, *, self_collision=False, angles=None):
    c = UNIT["obstacle_centers"] if centers is None else np.asarray(centers, float)
    h = UNIT["obstacle_half_sizes"] if halves is None else np.asarray(halves, float)
    return make_backend(name, c, h, LO, HI, self_collision=self_collision, obstacle_angles=angles)


def _chain(*points):
    """One configuration: a chain through the given joint points -> (1, L, 2) starts, ends."""
    P = np.asarray(points, dtype=float)
    return P[None, :-1], P[None, 1:]


def _disc(x, y):
    p = np.array([[[x, y]]], dtype=float)
    return p, p


# --------------------------------------------------------------------------------------------
# distance primitives against brute force


def _point_box_dist(p, c, h, ang):
    q = p - c
    cs, sn = np.cos(ang), np.sin(ang)
    loc = np.stack([cs * q[..., 0] + sn * q[..., 1], -sn * q[..., 0] + cs * q[..., 1]], -1)
    return np.linalg.norm(np.maximum(np.abs(loc) - h, 0.0), axis=-1)


def test_segment_rectangle_distance_matches_dense_sampling():
    rng = np.random.default_rng(0)
    n, s = 300, 4001
    a = rng.uniform(-3, 3, (n, 2))
    b = a + rng.normal(0, 1.5, (n, 2)) * (rng.uniform(size=(n, 1)) > 0.1)  # 10 % zero length
    c = rng.uniform(-1, 1, (n, 2))
    h = rng.uniform(0.2, 1.5, (n, 2))
    ang = rng.uniform(-np.pi, np.pi, n) * (rng.uniform(size=n) > 0.5)
    d = segment_rectangle_distance(a, b, c, h, ang)
    t = np.linspace(0, 1, s)[None, :, None]
    pts = a[:, None] + t * (b - a)[:, None]
    brute = _point_box_dist(pts, c[:, None], h[:, None], ang[:, None]).min(axis=1)
    seglen = np.linalg.norm(b - a, axis=1)
    assert np.all(d <= brute + 1e-12)  # exact distance is a lower bound of sampled distances
    assert np.all(brute - d <= seglen / (s - 1) + 1e-12)


def test_segment_segment_distance_matches_dense_sampling():
    rng = np.random.default_rng(1)
    n, s = 300, 2001
    a0, b0 = rng.uniform(-2, 2, (n, 2)), rng.uniform(-2, 2, (n, 2))
    a1 = a0 + rng.normal(0, 1, (n, 2)) * (rng.uniform(size=(n, 1)) > 0.1)
    b1 = b0 + rng.normal(0, 1, (n, 2)) * (rng.uniform(size=(n, 1)) > 0.1)
    d = segment_segment_distance(a0, a1, b0, b1)
    t = np.linspace(0, 1, s)[None, :, None]
    pa = a0[:, None] + t * (a1 - a0)[:, None]
    # distance from each sample of segment a to segment b (exact point-segment)
    db = b1 - b0
    dd = np.maximum((db * db).sum(-1), 1e-300)[:, None]
    tt = np.clip(((pa - b0[:, None]) * db[:, None]).sum(-1) / dd, 0, 1)[..., None]
    brute = np.linalg.norm(b0[:, None] + tt * db[:, None] - pa, axis=-1).min(axis=1)
    assert np.all(d <= brute + 1e-12)
    assert np.all(brute - d <= np.linalg.norm(a1 - a0, axis=1) / (s - 1) + 1e-12)


def test_segment_segment_distance_hand_cases():
    z = np.zeros(2)
    # crossing X
    assert segment_segment_distance([-1, -1], [1, 1], [-1, 1], [1, -1]) == 0.0
    # parallel, overlapping, 0.3 apart
    assert segment_segment_distance([0, 0], [2, 0], [1, 0.3], [3, 0.3]) == pytest.approx(0.3)
    # collinear disjoint
    assert segment_segment_distance([0, 0], [1, 0], [3, 0], [4, 0]) == pytest.approx(2.0)
    # two points
    assert segment_segment_distance(z, z, [3, 4], [3, 4]) == pytest.approx(5.0)


# --------------------------------------------------------------------------------------------
# hand cases, every backend


@pytest.mark.parametrize("name", BACKENDS)
class TestHandCases:
    r = 0.1

    def collide(self, name, se, **kw):
        return bool(_backend(name, **kw).capsules_collide(*se, self.r)[0])

    def test_protocol(self, name):
        assert isinstance(_backend(name), CollisionBackend)

    def test_disc_far_and_inside(self, name):
        assert not self.collide(name, _disc(3.0, 3.0))
        assert self.collide(name, _disc(0.2, -0.3))

    def test_disc_just_outside_and_inside_side(self, name):
        assert not self.collide(name, _disc(1.0 + self.r + 1e-3, 0.3))
        assert self.collide(name, _disc(1.0 + self.r - 1e-3, 0.3))

    def test_disc_near_corner(self, name):
        # AABB of the disc overlaps the square but the round disc misses the corner
        assert not self.collide(name, _disc(1.08, 1.08))  # distance 0.113 > r
        assert self.collide(name, _disc(1.06, 1.06))  # distance 0.085 < r

    def test_segment_touching_corner(self, name):
        assert self.collide(name, _chain([2.0, 2.0], [1.0, 1.0]))  # endpoint on the corner
        # corner at distance exactly-ish 1e-3 beyond r along the diagonal
        d = self.r + 1e-3
        assert not self.collide(name, _chain([1 + d / np.sqrt(2), 3.0], [1 + d / np.sqrt(2), 1 + d / np.sqrt(2)],
                                             [3.0, 1 + d / np.sqrt(2)]))

    def test_segment_passing_through(self, name):
        assert self.collide(name, _chain([-2.0, 0.5], [2.0, 0.5]))  # both endpoints outside
        assert self.collide(name, _chain([-2.0, -1.5], [1.5, 2.0]))  # diagonal through
        # diagonal segment cutting near the corner: AABBs overlap, true distance 0.354
        assert not self.collide(name, _chain([0.5, 2.0], [2.0, 0.5]))

    def test_segment_fully_inside(self, name):
        assert self.collide(name, _chain([-0.5, 0.0], [0.5, 0.2]))

    def test_workspace(self, name):
        x = LO[0] + self.r
        assert not self.collide(name, _disc(x + 1e-3, 0.0))
        assert self.collide(name, _disc(x - 1e-3, 0.0))
        assert self.collide(name, _chain([3.0, 3.0], [4.0, HI[1] + 0.05]))  # one end outside
        assert self.collide(name, _disc(np.nan, 0.0))

    def test_no_obstacles(self, name):
        kw = dict(centers=np.zeros((0, 2)), halves=np.zeros((0, 2)))
        assert not self.collide(name, _disc(0.0, 0.0), **kw)
        assert self.collide(name, _disc(HI[0], 0.0), **kw)

    def test_rotated_rectangle(self, name):
        kw = dict(halves=[[1.0, 0.1]], angles=[np.pi / 4])
        assert self.collide(name, _disc(0.5, 0.5), **kw)
        assert not self.collide(name, _disc(0.9, 0.0), **kw)  # would hit the unrotated bar
        assert self.collide(name, _disc(0.9, 0.0), halves=[[1.0, 0.1]])

    def test_self_collision_parallel_overlap(self, name):
        far = dict(centers=[[4.0, 4.0]], halves=[[0.1, 0.1]])
        # link 0 and link 2 parallel, 0.05 apart (< 2r), link 1 a short connector
        se = _chain([-2.0, -2.0], [-1.0, -2.0], [-1.0, -1.95], [-2.0, -1.95])
        assert self.collide(name, se, self_collision=True, **far)
        assert not self.collide(name, se, self_collision=False, **far)
        # same shape but 0.2 + 1e-3 apart: free
        se = _chain([-2.0, -2.0], [-1.0, -2.0], [-1.0, -1.799], [-2.0, -1.799])
        assert not self.collide(name, se, self_collision=True, **far)

    def test_adjacent_links_never_count(self, name):
        far = dict(centers=[[4.0, 4.0]], halves=[[0.1, 0.1]])
        # fully folded 2-link arm: link 1 lies on link 0
        assert not self.collide(name, _chain([-2.0, -2.0], [-1.0, -2.0], [-2.0, -2.0]), self_collision=True, **far)
        # zig-zag: every adjacent pair nearly overlaps, non-adjacent pairs are > 2r apart
        se = _chain([-3, -3], [-1, -3], [-3, -2.7], [-1, -2.4], [-3, -2.1])
        assert not self.collide(name, se, self_collision=True, **far)

    def test_crossing_nonadjacent_links(self, name):
        far = dict(centers=[[4.0, 4.0]], halves=[[0.1, 0.1]])
        se = _chain([-3, -3], [-1, -1], [-1, -3], [-3, -1])  # links 0 and 2 cross
        assert self.collide(name, se, self_collision=True, **far)

    def test_pairs_are_by_index(self, name):
        # links 0 and 2 share the point (1, 0) through a zero-length link 1: |0 - 2| = 2, counted
        far = dict(centers=[[4.0, 4.0]], halves=[[0.1, 0.1]])
        se = _chain([0, 0], [1, 0], [1, 0], [2, 0])
        assert self.collide(name, se, self_collision=True, **far)

    def test_empty(self, name):
        b = _backend(name, self_collision=True)
        assert b.capsules_collide(np.zeros((0, 3, 2)), np.zeros((0, 3, 2)), 0.1).shape == (0,)
        assert not b.capsules_collide(np.zeros((2, 0, 2)), np.zeros((2, 0, 2)), 0.1).any()


def test_nonadjacent_pairs():
    a, b = nonadjacent_pairs(4)
    assert sorted(zip(a.tolist(), b.tolist())) == [(0, 2), (0, 3), (1, 3)]
    assert nonadjacent_pairs(2)[0].size == 0


# --------------------------------------------------------------------------------------------
# cross-check numpy vs fcl (and prefilter off, numba, clearance) on random ensembles


def _world(rng, rotated):
    K = 6
    centers = rng.uniform(-3.5, 3.5, (K, 2))
    halves = rng.uniform(0.2, 0.9, (K, 2))
    angles = rng.uniform(-np.pi, np.pi, K) if rotated else None
    return centers, halves, angles


def _random_chains(rng, n, centers):
    """Chains of 1..8 links, bases near obstacles; some zero-length links. -> list of (S, E)."""
    out = []
    for L in range(1, 9):
        m = n // 8
        base = centers[rng.integers(len(centers), size=m)] + rng.normal(0, 1.2, (m, 2))
        lengths = rng.uniform(0.1, 0.8, L)
        theta = rng.uniform(-np.pi, np.pi, (m, L))
        S, E = link_segments(theta, lengths)
        P = np.concatenate([S, E[:, -1:]], axis=1) + base[:, None]  # (m, L+1, 2) joint points
        # collapse one link j to zero length in 10 % of the configurations (shift joints after it)
        z = np.flatnonzero(rng.uniform(size=m) < 0.1)
        j = rng.integers(L, size=z.size)
        d = P[z, j + 1] - P[z, j]
        after = np.arange(L + 1)[None, :] > j[:, None]
        P[z] -= after[:, :, None] * d[:, None, :]
        S, E = P[:, :-1], P[:, 1:]
        out.append((S, E))
    return out


def _random_discs(rng, n, centers, halves, angles, r):
    """Discs near obstacle boundaries: a boundary point plus an offset of order r."""
    k = rng.integers(len(centers), size=n)
    u = rng.uniform(-1, 1, (n, 2))
    side = rng.integers(2, size=n)
    u[np.arange(n), side] = np.sign(u[np.arange(n), side] + 1e-12)  # on an edge
    local = u * halves[k] + rng.normal(0, 1.5 * r, (n, 2))
    if angles is not None:
        c, s = np.cos(angles[k]), np.sin(angles[k])
        local = np.stack([c * local[:, 0] - s * local[:, 1], s * local[:, 0] + c * local[:, 1]], -1)
    p = (centers[k] + local)[:, None, :]
    return p, p.copy()


@pytest.mark.parametrize("rotated", [False, True])
@pytest.mark.parametrize("self_collision", [False, True])
def test_cross_check_numpy_fcl(rotated, self_collision):
    rng = np.random.default_rng(1234 + 2 * rotated + self_collision)
    centers, halves, angles = _world(rng, rotated)
    r = 0.08
    kw = dict(self_collision=self_collision, obstacle_angles=angles)
    npb = make_backend("numpy", centers, halves, LO, HI, **kw)
    npb_full = make_backend("numpy", centers, halves, LO, HI, prefilter=False, **kw)
    nbb = make_backend("numba", centers, halves, LO, HI, **kw)
    fclb = make_backend("fcl", centers, halves, LO, HI, **kw)
    batches = _random_chains(rng, 2400, centers) + [_random_discs(rng, 1000, centers, halves, angles, r)]
    total = skipped = collided = 0
    for S, E in batches:
        a = npb.capsules_collide(S, E, r)
        clear = npb.clearance(S, E, r)
        keep = np.abs(clear) >= BAND
        np.testing.assert_array_equal(a[keep], (clear < 0)[keep])
        np.testing.assert_array_equal(a, npb_full.capsules_collide(S, E, r))
        np.testing.assert_array_equal(a[keep], nbb.capsules_collide(S, E, r)[keep])
        f = fclb.capsules_collide(S, E, r)
        bad = np.flatnonzero(keep & (a != f))
        assert bad.size == 0, f"numpy/fcl disagree at {bad[:5]} (clearance {clear[bad[:5]]})"
        total += len(a)
        skipped += int((~keep).sum())
        collided += int(a.sum())
    assert total >= 3000
    assert skipped <= 0.01 * total
    assert 0.15 * total < collided < 0.85 * total  # both outcomes well represented


def test_cross_check_near_contact_discs():
    """Discs at clearance +-1e-4 .. 1e-2 from a rectangle's sides and corners: decided the same."""
    rng = np.random.default_rng(7)
    r = 0.1
    npb = _backend("numpy")
    fclb = _backend("fcl")
    n = 400
    ang = rng.uniform(-np.pi, np.pi, n)
    # closest point on the unit square's boundary in direction ang, then push out by r + eps
    q = np.stack([np.cos(ang), np.sin(ang)], -1)
    q = q / np.abs(q).max(axis=1, keepdims=True)
    nrm = np.where(np.abs(q) >= 1 - 1e-12, np.sign(q), 0.0)
    corner = (np.abs(q) >= 1 - 1e-12).all(axis=1)
    nrm[corner] = q[corner] / np.sqrt(2)
    eps = rng.choice([-1e-2, -1e-3, -1e-4, 1e-4, 1e-3, 1e-2], size=n)
    p = (q + (r + eps)[:, None] * nrm)[:, None, :]
    a = npb.capsules_collide(p, p, r)
    np.testing.assert_array_equal(a, eps < 0)
    np.testing.assert_array_equal(a, fclb.capsules_collide(p, p, r))


# --------------------------------------------------------------------------------------------
# construction and input errors


def test_make_backend_names():
    assert isinstance(_backend("numpy"), NumpyCollisionBackend)
    assert isinstance(_backend("fcl"), FclCollisionBackend)
    with pytest.raises(InputError):
        make_backend("bullet", np.zeros((0, 2)), np.zeros((0, 2)), LO, HI, self_collision=False)


@pytest.mark.parametrize("name", ["numpy", "fcl"])
def test_input_errors(name):
    with pytest.raises(InputError):
        make_backend(name, np.zeros((1, 2)), np.zeros((1, 2)), LO, HI, self_collision=False)  # zero half size
    with pytest.raises(InputError):
        make_backend(name, np.zeros((2, 2)), np.ones((1, 2)), LO, HI, self_collision=False)
    with pytest.raises(InputError):
        make_backend(name, np.zeros((1, 2)), np.ones((1, 2)), HI, LO, self_collision=False)
    with pytest.raises(InputError):
        make_backend(name, np.zeros((1, 2)), np.ones((1, 2)), LO, HI, self_collision=False, obstacle_angles=[0, 1])
    b = _backend(name)
    S = np.zeros((3, 2, 2))
    with pytest.raises(InputError):
        b.capsules_collide(S, S, 0.0)
    with pytest.raises(InputError):
        b.capsules_collide(S, S, -1.0)
    with pytest.raises(InputError):
        b.capsules_collide(S[0], S[0], 0.1)
    with pytest.raises(InputError):
        b.capsules_collide(S, S[:, :1], 0.1)
