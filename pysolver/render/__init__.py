"""The render stage: OpenSCAD part files and STLs from the design tables.

Modules: :mod:`.scad_io` (part files, SCAD library), :mod:`.parts` (renderers and the part
cache), :mod:`.fast` (the fast part renderer), :mod:`.solids` (STL meshes, manifold3d
unions) and :mod:`.layers` (the stage: :func:`render_design` unites the parts into layers
and writes ``stl/``).  Beside the stage, from the same SCAD modules: :mod:`.specimens`, the
printable unit-cell test specimens (``morphshell specimens``).
"""
from .layers import STL_FILES, render_design
from .parts import (
    DEFAULT_RENDERER,
    OPENSCAD_ENV,
    RENDERERS,
    RendererFallbackWarning,
    check_renderer,
    default_cache_dir,
    fast_self_check,
    find_openscad,
    library_digest,
    openscad_version,
    part_key,
    render_parts,
    start_self_check,
)
from .solids import describe_stl, from_manifold, load_stl, to_manifold, union

__all__ = [
    "DEFAULT_RENDERER",
    "OPENSCAD_ENV",
    "RENDERERS",
    "RendererFallbackWarning",
    "STL_FILES",
    "check_renderer",
    "default_cache_dir",
    "describe_stl",
    "fast_self_check",
    "find_openscad",
    "from_manifold",
    "library_digest",
    "load_stl",
    "openscad_version",
    "part_key",
    "render_design",
    "render_parts",
    "start_self_check",
    "to_manifold",
    "union",
]
