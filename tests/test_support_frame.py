"""Support frame: every breakaway connector reaches the ring, checked on the rendered STL.

The test shell is a flat U (an equilateral lattice with a notch narrower than twice the
ring's inner offset), designed from a stencil OBJ written here: in the notch the ring
(an offset of the whole outline) lies much farther than ``offset_out`` from the bases'
own edges, so a connector of fixed length would end short there (what petal showed:
3 of 13 connectors ended 3-6 mm short, in the notches between its petals).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from matplotlib.path import Path as MplPath

from pysolver.params import SUPPORT_FRAME as SF
from pysolver.params import UNIT_CELL as U
from pysolver.render.scad_io import (
    boundary_edges,
    frame_connectors,
    frame_holes,
    ring_reach,
    write_part_files,
)
from pysolver.tables import read_design, write_stencil


def u_patch(nx=10, ny=9, notch=(4.4, 5.4, 3.0)):
    """Equilateral lattice (unit edge) clipped to a U.

    Returns
    -------
    V : (n, 2) float -- unitless (the design scales it with ``size``)
    F : (m, 3) int
    """
    h = math.sqrt(3) / 2
    idx = np.arange((ny + 1) * (nx + 1)).reshape(ny + 1, nx + 1)
    jj, ii = np.divmod(np.arange((ny + 1) * (nx + 1)), nx + 1)
    pts = np.c_[ii + 0.5 * (jj % 2), jj * h]
    tris = []
    for j in range(ny):
        for i in range(nx):
            a, b, c, d = idx[j, i], idx[j, i + 1], idx[j + 1, i], idx[j + 1, i + 1]
            tris += [(a, b, c), (b, d, c)] if j % 2 == 0 else [(a, b, d), (a, d, c)]
    F = np.array(tris)
    x0, x1, y0 = notch
    C = pts[F].mean(1)
    F = F[~((C[:, 0] > x0) & (C[:, 0] < x1) & (C[:, 1] > y0 * h))]
    used = np.unique(F)
    remap = np.full(len(pts), -1)
    remap[used] = np.arange(len(used))
    return pts[used], remap[F]


def _outline_distance(P, X):
    """Distance (mm) from points X (k, 2) to the closed polygon P (b, 2)."""
    A, B = P, np.roll(P, -1, axis=0)
    AB = B - A
    t = np.clip(np.einsum("kij,ij->ki", X[:, None] - A, AB) / np.sum(AB * AB, 1), 0, 1)
    return np.linalg.norm(X[:, None] - (A + t[..., None] * AB), axis=2).min(1)


# notch (x0, x1) in lattice units: narrow everywhere (< 2 offset_in), or wider inside than
# at its zig-zag mouth, so the ring's inner offset has holes (loose ring islands before the
# holes were filled)
NOTCHES = {"narrow": (4.4, 5.4), "bottleneck": (4.4, 5.6)}


@pytest.fixture(scope="module", params=sorted(NOTCHES))
def design(tmp_path_factory, request):
    from pysolver.design import run_design

    root = tmp_path_factory.mktemp(f"frame_{request.param}")
    V2, F = u_patch(notch=(*NOTCHES[request.param], 3.0))
    write_stencil(root / "u.obj", np.c_[V2, np.zeros(len(V2))], V2, F)
    run_design(root / "u.obj", root / "d", size=60.0, plots=False, progress=False)
    return read_design(root / "d"), root, request.param


def test_holes_of_the_inner_offset(design):
    """The bottleneck notch leaves holes in the inner offset (3 here), the narrow one none;
    every hole point is farther than offset_in from the outline, up to the margin."""
    d, _, kind = design
    holes = frame_holes(d.support)
    assert len(holes) == (3 if kind == "bottleneck" else 0)
    for h in holes:
        r = _outline_distance(d.support, h)
        assert r.min() >= SF.offset_in - SF.hole_margin - 1e-3


def test_a_fixed_length_would_end_short_in_the_notch(design):
    """The test shape has the petal's problem: from some boundary bases the fixed-length
    connector (edge distance + offset_out - bar width) ends outside the ring."""
    d, _, _kind = design
    P = d.support
    ends = np.array([c + (dist + SF.offset_out - SF.connector_w) * n
                     for _b, c, n, dist in boundary_edges(d)])
    r = _outline_distance(P, ends)
    short = (r < SF.offset_in) | MplPath(P).contains_points(ends)
    assert short.sum() >= 3


def test_every_connector_ends_in_the_ring(design):

    d, _, _kind = design
    P = d.support
    holes = frame_holes(P)
    con = frame_connectors(d)
    assert len(con) >= 4
    C = np.array([c for c, _a, _l in con])
    u = np.array([[math.cos(math.radians(a)), math.sin(math.radians(a))] for _c, a, _l in con])
    L = np.array([l for _c, _a, l in con])
    r_end = _outline_distance(P, C + L[:, None] * u)
    mid = 0.5 * (SF.offset_in + SF.offset_out)
    assert r_end == pytest.approx(np.full(len(con), mid), abs=SF.step)
    for h in holes:  # not in a filled hole
        assert not MplPath(h).contains_points(C + L[:, None] * u).any()
    # and every point of the bar beyond its base stays outside the shell
    for c, uu, length in zip(C, u, L, strict=True):
        s = np.linspace(U.base_r + 1.0, length, 200)
        assert not MplPath(P).contains_points(c + s[:, None] * uu).any()
    # spacing rule of the greedy choice kept
    D = np.linalg.norm(C[:, None] - C[None], axis=2) + np.eye(len(C)) * 1e9
    assert D.min() >= SF.spacing


def test_ring_reach_refuses_a_ray_across_the_shell():
    """A ray that meets the outline's interior again (across a notch) gets no connector."""
    square = np.array([[0, 0], [10, 0], [10, 10], [0, 10]], float)
    assert ring_reach(square, np.array([5.0, 8.0]), np.array([0.0, 1.0]), 2.0) == \
        pytest.approx(2.0 + 0.5 * (SF.offset_in + SF.offset_out), abs=SF.step)
    notch = np.array([[0, 0], [30, 0], [30, 30], [17, 30], [17, 10], [13, 10], [13, 30],
                      [0, 30]], float)
    # from the left wall of the notch toward the right wall (4 mm away): refused
    assert ring_reach(notch, np.array([11.0, 20.0]), np.array([1.0, 0.0]), 2.0) is None
    # from the notch bottom up: the ring lies beyond the mouth, 20 mm + 7.5 mm away: too far
    assert ring_reach(notch, np.array([15.0, 8.0]), np.array([0.0, 1.0]), 2.0) is None


def test_frame_stl_is_one_body_and_every_connector_joins_base_and_ring(design):
    """Rendered with OpenSCAD: the frame of each layer is one connected body (ring plus
    bars, so no bar ends short of the ring), and each bar is present inside its base disc
    (at r0 + 0.3 mm from the centre, < base_r) and at its end."""
    import manifold3d

    from pysolver.render import load_stl, render_parts, to_manifold

    d, root, _kind = design
    parts = [p for p in write_part_files(root / "d", root / "scad", actuated=False, design=d)
             if p.kind == "frame"]
    res = render_parts(parts, cache_dir=root / "cache", progress=False, renderer="openscad")
    con = frame_connectors(d)
    probe = 0.2  # mm, side of the probe cube (inside the 0.5 mm bar)
    for p in parts:
        mesh = load_stl(res["stl"][p.name])
        assert mesh.is_watertight
        assert len(mesh.split(only_watertight=False)) == 1, p.name
        solid = to_manifold(mesh)
        sign = 1.0 if p.layer == "top" else -1.0
        z = sign * (U.layer_h - SF.connector_w / 2)
        for c, a, length in con:
            u = np.array([math.cos(math.radians(a)), math.sin(math.radians(a))])
            for s in (SF.connector_r0 + 0.3, length - 0.3):
                x, y = c + s * u
                box = manifold3d.Manifold.cube([probe] * 3, True).translate([x, y, z])
                assert (solid ^ box).volume() == pytest.approx(probe ** 3, rel=1e-3), \
                    (p.name, c, s)
            assert SF.connector_r0 + 0.3 < U.base_r
