"""Provenance: file hashes, package versions and the lock-file record, in one place.

A build's ``summary.json`` (:func:`pysolver.build.build`), its input hash and the report's
provenance table (:func:`sim.report.fabrication.provenance`) all read them from here.
"""

from __future__ import annotations

import hashlib
import importlib.metadata
import sys
import tomllib
from pathlib import Path

VERSION_PACKAGES = ("morphshell", "numpy", "scipy", "libigl", "trimesh", "manifold3d",
                    "triangle", "pymeshlab", "scikit-sparse", "qpsolvers", "matplotlib",
                    "pyvista", "openscad-evaluator", "autograd", "numba")
"""Packages whose versions a build and its report record."""

LOCK_FILE = Path(__file__).resolve().parents[2] / "uv.lock"
"""The lock file that ``make`` installs (absent when morphshell is installed some other way)."""

NOT_INSTALLED = "not installed"


def sha256_file(path) -> str:
    """Hex SHA-256 of a file's bytes, read in 1 MiB chunks."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def package_version(dist: str) -> str:
    """Installed version of a distribution, or ``"not installed"``."""
    try:
        return importlib.metadata.version(dist)
    except importlib.metadata.PackageNotFoundError:
        return NOT_INSTALLED


def package_versions(names=VERSION_PACKAGES) -> dict:
    """``{name: version}`` of ``names`` and ``python``."""
    v = {name: package_version(name) for name in names}
    v["python"] = sys.version.split()[0]
    return v


def lock_record(lock=LOCK_FILE) -> dict:
    """The lock file's hash, and the installed packages whose version it does not pin.

    Returns
    -------
    dict
        ``sha256`` of ``uv.lock`` (None when there is none), ``mismatched``: sorted
        ``"name installed (lock: v1, v2)"`` for every package the lock pins that is installed
        at another version (empty when the environment is exactly the lock's).
    """
    lock = Path(lock)
    if not lock.is_file():
        return {"sha256": None, "mismatched": []}
    data = tomllib.loads(lock.read_text(encoding="utf-8"))
    pinned: dict = {}
    for pkg in data.get("package", []):
        if "version" in pkg and (pkg.get("source") or {}).get("editable") is None:
            pinned.setdefault(pkg["name"], set()).add(pkg["version"])
    bad = []
    for name, vers in sorted(pinned.items()):
        have = package_version(name)
        if have != NOT_INSTALLED and have not in vers:
            bad.append(f"{name} {have} (lock: {', '.join(sorted(vers))})")
    return {"sha256": sha256_file(lock), "mismatched": bad}


def environment_versions(lock=LOCK_FILE) -> dict:
    """:func:`package_versions` plus the lock file's record (``lock_sha256``,
    ``lock_mismatched``, :func:`lock_record`)."""
    v = package_versions()
    rec = lock_record(lock)
    v["lock_sha256"] = rec["sha256"]
    v["lock_mismatched"] = rec["mismatched"]
    return v


__all__ = ["VERSION_PACKAGES", "LOCK_FILE", "sha256_file", "package_version",
           "package_versions", "lock_record", "environment_versions"]
