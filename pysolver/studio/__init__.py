"""``morphshell studio``: the researcher's front end in the browser (morph viewer,
time-landscape editor, side-by-side builds).  See :mod:`pysolver.studio.server`."""

from .server import serve

__all__ = ["serve"]
