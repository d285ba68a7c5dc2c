"""Every built-in shape renders to watertight STLs (issue: "the STLs are watertight").

Each default built-in shape is designed and programmed (its thicknesses vary per cell and
layer, as printed) as ``build(name, simulate=False)`` does it, then rendered with the fast
renderer (openscad-evaluator; its parts agree with Debian OpenSCAD's,
``tests/test_render_fast.py``) including the actuated preview.  Every written STL, re-read
from its float32 file, must be watertight and a volume; each printed layer must be one
solid.  The design is the session's shared one (``_shared.designed``, the same
``run_design(name)`` whose golden figures ``tests/test_surfaces.py`` checks), programmed
and rendered here on a copy.  (The Debian OpenSCAD renderer takes 1-3 min per shape on 2
cores: its figures are in the build summaries, not here.)
"""

from __future__ import annotations

import shutil

import numpy as np
import pytest
import trimesh
from _shared import designed

from pysolver.design import surfaces
from pysolver.render import render_design
from pysolver.temporal import program_design


def _nonmanifold_edges(m: trimesh.Trimesh) -> int:
    _, counts = np.unique(np.sort(m.edges, axis=1), axis=0, return_counts=True)
    return int((counts != 2).sum())


# (in the reverse of tests/test_surfaces.py's order: run side by side on two workers, the two
# files design different shapes first and meet in the middle, rather than one waiting)
# (mechtest is regular's lattice at twice its size: regular's STLs cover it, for make test's time)
@pytest.mark.parametrize("name", [n for n in surfaces.BUILTIN if n != "mechtest"][::-1])
def test_builtin_shape_stls_are_watertight(name, tmp_path, tmp_path_factory):
    out = tmp_path / name
    shutil.copytree(designed(name, tmp_path_factory), out)
    # the build's program and render stages (pysolver/stages/runners.py), the fast renderer
    program_design(out, progress=False, picture=False, fit_landscape=True)
    render_design(out, jobs=1, progress=False, renderer="fast")
    stls = sorted((out / "stl").glob("*.stl"))
    assert {p.stem for p in stls} >= {"top", "bottom", "actuated", "support_frame_top",
                                       "support_frame_bottom", "markers_top", "markers_bottom"}
    for p in stls:
        m = trimesh.load(p, force="mesh")
        assert m.is_watertight and m.is_volume, f"{name}/{p.name}: {_nonmanifold_edges(m)} " \
                                                "non-manifold edges"
        if p.stem in ("top", "bottom"):
            assert m.body_count == 1, f"{name}/{p.name} is {m.body_count} solids"
