"""``morphshell studio``: the researcher's front end in the browser (paint the time landscape
on the target, build it again, see the verdict and the parts, the morph against the target,
builds side by side).  See :mod:`pysolver.studio.server` and ``docs/studio.md``."""

from .server import serve

__all__ = ["serve"]
