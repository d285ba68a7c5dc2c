"""Collision detection along a morph (sim.model.collisions)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from test_report import make_synthetic_design

from sim.model.collisions import (
    _pair_penetration,
    base_collisions,
    cylinder_samples,
    cylinder_sdf,
    membrane_collisions,
)

R_BASE, H = 2.0, 2.3            # base radius, half height (mm)
I3 = np.eye(3)


def one_frame(centres, rotations=None):
    C = np.asarray(centres, float)[None]
    R = np.broadcast_to(I3, C.shape[:2] + (3, 3)).copy() if rotations is None else \
        np.asarray(rotations, float)[None]
    return C, R


def test_cylinder_sdf_closed_form():
    c, a = np.zeros(3), np.array([0.0, 0.0, 1.0])
    P = np.array([[0, 0, 0],          # centre: inside by min(r, h) = 2
                  [3, 0, 0],          # beside: 1 mm outside the side
                  [0, 0, 3.3],        # above: 1 mm above the cap
                  [5, 0, 6.3],        # beyond the rim: hypot(3, 4) = 5
                  [1.5, 0, 2.0]])     # inside, 0.3 below the cap, 0.5 from the side
    np.testing.assert_allclose(cylinder_sdf(P, c, a), [-2.0, 1.0, 1.0, 5.0, -0.3], atol=1e-12)
    # rotation invariance
    G = Rotation.from_rotvec([0.4, -1.1, 0.7])
    np.testing.assert_allclose(cylinder_sdf(G.apply(P) + 1.0, 1.0 + G.apply(c), G.apply(a)),
                               cylinder_sdf(P, c, a), atol=1e-12)


@pytest.mark.parametrize("gap,collides", [(-0.15, True), (-0.05, False), (0.3, False)])
def test_side_by_side(gap, collides):
    C, R = one_frame([[0, 0, 0], [2 * R_BASE + gap, 0, 0]])
    res = base_collisions(C, R, np.zeros((0, 2), int), tol=0.1)
    assert (res.count == 1) == collides
    # the sampled clearance is the true gap here (rims face each other at sample points)
    assert res.min_clearance[0] == pytest.approx(gap, abs=1e-9)


def test_stacked_and_tilted():
    # coaxial, 0.2 mm overlap along the axis
    C, R = one_frame([[0, 0, 0], [0, 0, 2 * H - 0.2]])
    res = base_collisions(C, R, [], tol=0.1)
    assert res.count == 1 and res.depth[0] == pytest.approx(0.2, abs=1e-9)
    # B turned 90 deg (axis along x), its cap 0.3 mm inside A's side
    Rb = Rotation.from_rotvec([0, np.pi / 2, 0]).as_matrix()
    C, R = one_frame([[0, 0, 0], [R_BASE + H - 0.3, 0, 0]], [I3, Rb])
    res = base_collisions(C, R, [], tol=0.1)
    assert res.count == 1 and res.depth[0] == pytest.approx(0.3, abs=1e-9)
    # the same pair listed as neighbours (they share a unit cell) is not checked
    assert base_collisions(C, R, [[1, 0]], tol=0.1).count == 0


def test_kdtree_broad_phase_misses_nothing():
    rng = np.random.default_rng(0)
    n = 80
    C = rng.uniform(0, 30, (3, n, 3))
    R = Rotation.random(3 * n, random_state=1).as_matrix().reshape(3, n, 3, 3)
    nb = np.array([[0, 1], [2, 3], [5, 9]])
    res = base_collisions(C, R, nb, tol=0.1)
    samples = cylinder_samples()
    expected = set()
    i, j = np.triu_indices(n, 1)
    keep = ~np.isin(i * n + j, nb[:, 0] * n + nb[:, 1])
    i, j = i[keep], j[keep]
    for f in range(3):
        clr, _ = _pair_penetration(C[f, i], R[f, i], C[f, j], R[f, j], samples, R_BASE, H)
        expected |= set(zip(i[clr < -0.1].tolist(), j[clr < -0.1].tolist(), strict=True))
    assert len(expected) > 5
    assert {tuple(p) for p in res.pairs.tolist()} == expected


@pytest.fixture(scope="module")
def clean(tmp_path_factory):
    d = tmp_path_factory.mktemp("clean")
    return make_synthetic_design(d, n=7, mode="good")


def test_clean_morph_has_no_collision(clean):
    fr = clean["frames"]
    nb = clean["cells"].faces
    bc = base_collisions(fr["base_center"], fr["base_rotation"], nb, t=fr["t"])
    assert bc.count == 0 and bc.first() is None
    # any non-neighbouring pair that came near stayed > 0.5 mm apart
    assert np.all(bc.min_clearance > 0.5)
    mc = membrane_collisions(fr["base_center"], fr["base_rotation"], fr["membrane_vertices"],
                             t=fr["t"])
    assert mc.count == 0


def test_interpenetrating_bases_are_flagged(tmp_path):
    data = make_synthetic_design(tmp_path, n=6, mode="collide")
    fr = data["frames"]
    bc = base_collisions(fr["base_center"], fr["base_rotation"], data["cells"].faces, t=fr["t"])
    nf = len(fr["t"])
    assert bc.count == 1
    ev = bc.first()
    assert ev["pair"][0] == 0 and ev["frame"] == nf // 2 and ev["time_s"] == fr["t"][nf // 2]
    assert (bc.n_colliding[nf // 2:] == 1).all() and (bc.n_colliding[:nf // 2] == 0).all()
    # the deepest point lies inside both cylinders
    p = np.array(ev["point_mm"])
    f = ev["frame"]
    for b in ev["pair"]:
        assert cylinder_sdf(p, fr["base_center"][f, b], fr["base_rotation"][f, b, :, 2]) < 1e-9


def test_membrane_through_far_base_is_flagged(clean):
    fr = clean["frames"]
    C, R = fr["base_center"], fr["base_rotation"]
    M = fr["membrane_vertices"].copy()
    k = len(fr["t"]) - 5
    flat = np.c_[clean["C2"], np.zeros(len(clean["C2"]))]
    # vertex 0 (a corner of the lattice) into the farthest base, from frame k on
    far = int(np.argmax(np.linalg.norm(flat - M[0, 0], axis=1)))
    M[k:, 0] = C[k:, far] + 0.5 * R[k:, far, :, 2]
    # vertex 1 into a base it borders (local in the flat layout): allowed
    near = int(np.argmin(np.linalg.norm(flat - M[0, 1], axis=1)))
    M[k:, 1] = C[k:, near]
    mc = membrane_collisions(C, R, M, t=fr["t"])
    assert mc.count == 1
    assert mc.first()["pair"] == [0, far] and mc.first()["frame"] == k
    # 0.5 mm above the mid-plane: 1.8 mm below the cap, 2 mm from the side
    assert mc.depth[0] == pytest.approx(H - 0.5, abs=1e-6)
