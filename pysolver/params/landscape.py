"""The time landscape: the automatic sequencing landscape of a mesh given no times.

Source: morphshell's; the paper's cover closes its parts between 30 and 80 s.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Sequencing:
    """Settings of the automatic sequencing landscape (:mod:`pysolver.design.sequencing`):
    where parts of the target lie over other parts (the petals of a closed bud), the part
    underneath must be in place before the one on top arrives, else they jam halfway.

    Source: morphshell's (the paper sequences its cover by hand); measurements with the
    fields.

    Attributes
    ----------
    reach_mm : float, mm
        Two points of the target closer than this, in space, face each other ...
    detour : float
        ... when the path between them on the surface is over ``detour`` times longer.
    min_pairs : int
        Fewest facing vertex pairs that make an overlap (fewer are ignored as noise).
    saddle_ratio : float
        Two lobes of the surface (watershed basins of the distance to the rim) stay apart when
        the neck between them is under ``saddle_ratio`` of the smaller lobe's half-width;
        wider necks merge them into one part.
    times_s : (2,) float, s
        Completion times of the first and of the last part (the paper's cover: 30-80 s).
    min_separation_s : float, s
        When the build maps a sequenced landscape onto the times the cells can reach
        (``program_design(fit_landscape=True)``), successive parts stay at least this far
        apart.  The map that clamps fewest cells alone squeezed the cover's 30-80 s into
        58-59 s; the simulated completion times scatter by an RMS 9-11 s around ``t*``
        (:mod:`pysolver.temporal.program`), so parts closer than that may close together.
    bytes_per_pair : int, bytes
        Memory the facing-pair search holds per vertex pair within ``reach_mm``: the pair
        list (2 x int64, also while scipy builds it), its sort order, and the distance and
        path arrays (float64); counted from the code of
        :func:`pysolver.design.sequencing.facing_pairs`.
    memory_fraction : float
        Share of the machine's available memory the pair search may take; a denser input
        mesh is refused before the search, naming the number of faces that would fit.
    estimate_samples : int
        Vertices (evenly spaced in file order) whose neighbours within ``reach_mm`` are
        counted to estimate the number of pairs before the search.
    """

    reach_mm: float = 12.0
    detour: float = 3.0
    min_pairs: int = 20
    saddle_ratio: float = 0.75
    times_s: tuple = (30.0, 80.0)
    min_separation_s: float = 10.0
    bytes_per_pair: int = 72
    memory_fraction: float = 0.5
    estimate_samples: int = 2000


SEQUENCING = Sequencing()

__all__ = ["Sequencing", "SEQUENCING"]
