"""The stencil search: which triangle mesh of a target surface to print (SI Note 2).

A stencil is a coarse triangulation of the target whose unit cells (one per edge) print
flat.  Finding it is a search, in the order a reader meets it:

* :mod:`.remesh` -- candidate stencils: a CVT in the conformal plane of the (dense-resampled)
  target, seeded in a frame the target's shape sets (:class:`FlatDomain`), or pymeshlab's
  isotropic remeshing;
* :mod:`.optimise` -- the stencil optimisation: vertices moved on the target to shorten the
  longest flat cell (and, with a time landscape, to even the cells' speeds against it);
  :mod:`.objective` is its objective and gradient, written once;
* :mod:`.candidates` -- a candidate (:class:`Candidate`: vertex count, CVT seed, rim inset),
  its figures (:func:`stencil_figures`), the rules "keeps the size" (:func:`at_size`,
  :func:`full_size`) and "prints with the margin" (:func:`prints`), and the pick among the
  candidates (:func:`pick`);
* :mod:`.count_search` -- the vertex-count search over one target (:class:`CountSearch`:
  secant steps, rim fallback, polish, trade);
* :mod:`.search` -- :func:`remesh_surface`, the entry point: one search, then the search
  without the time grading or with the rim's scale free when the first does not print;
* :mod:`.feasibility` -- the measured bound on the longest flat cell of any stencil of a
  target (why a target cannot print at its size);
* :mod:`.alternatives` -- a refused size's measured alternatives (a smaller ``--size``).

The design stage (:mod:`pysolver.design.pipeline`) uses the names below and nothing else of
this package (``tests/test_architecture.py`` keeps it so).
"""
from .alternatives import printable_alternatives, size_refusal
from .candidates import (
    Candidate,
    at_size,
    full_size,
    pick,
    prints,
    prints_at_full_size,
    stencil_figures,
)
from .remesh import surface_area
from .search import remesh_surface

__all__ = [
    "Candidate",
    "at_size",
    "full_size",
    "pick",
    "printable_alternatives",
    "prints",
    "prints_at_full_size",
    "remesh_surface",
    "size_refusal",
    "stencil_figures",
    "surface_area",
]
