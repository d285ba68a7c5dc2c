"""The render stage: OpenSCAD part files and STLs from the design tables.

Modules: :mod:`.scad_io` (part files, SCAD library), :mod:`.parts` (renderers, the part
cache, union, :func:`render_design`) and :mod:`.fast` (the fast part renderer).
"""
from .parts import (
    DEFAULT_RENDERER,
    OPENSCAD_ENV,
    RENDERERS,
    STL_FILES,
    RendererFallbackWarning,
    check_renderer,
    default_cache_dir,
    describe_stl,
    fast_self_check,
    find_openscad,
    from_manifold,
    library_digest,
    load_stl,
    openscad_version,
    part_key,
    render_design,
    render_parts,
    start_self_check,
    to_manifold,
    union,
)

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
