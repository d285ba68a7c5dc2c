"""One build folder as the studio sends it: its target, landscape and feasibility, the
morph viewer's data, the report's figures and the parts (loaded lazily, cached, dropped
after a run), and the checks a Run must pass before it may start (:class:`Build`).

Nothing here writes: the folder is read, and a Run is :mod:`pysolver.studio.jobs`'s."""

from __future__ import annotations

import gzip
import json
import re
import threading
import time
from pathlib import Path

import numpy as np

from ..build import rebuild_inputs_hash, report_figures
from ..design.time_landscape import cell_target_times
from ..errors import InputError, MorphshellError
from ..params import LIMITS, PROGRAMMING
from ..simulator import build_parts, completion_times, morph_viewer
from ..tables import (
    LANDSCAPE_SOURCE,
    TABLE_FILES,
    predicted_timing_sd,
    read_record,
    read_stencil,
    read_table,
    round_sig9,
)
from ..temporal import STAGE_FILE
from .landscape import (
    Feasibility,
    harmonic_landscape,
    keyframe_values,
    parse_keyframes,
    parse_landscape,
    parse_landscape_csv,
    run_base_sha256,
)

STL_NAME = re.compile(r"[a-z][a-z0-9_]{0,63}\.stl")
"""STL names the studio serves (and only those listed in ``stl/``)."""


class Stale(MorphshellError):
    """A Run whose landscape was not edited from the build's current one: another build's,
    or this build's before it was built again (HTTP 409)."""


_TARGET_FILES = ("stencil.obj", "time_landscape.csv", "cells.csv", STAGE_FILE, "sim/frames.npz",
                 "sim/refine.json", LANDSCAPE_SOURCE)
"""The files :meth:`Build.target` is made from (``sim/refine.json``: the cells' predicted
timing sd, :func:`pysolver.tables.predicted_timing_sd`)."""


def _stamps(folder: Path, names) -> tuple:
    """``(size, mtime_ns)`` of each file (None when absent): changes when one is written."""
    out = []
    for n in names:
        try:
            st = (folder / n).stat()
            out.append((st.st_size, st.st_mtime_ns))
        except OSError:
            out.append(None)
    return tuple(out)


def _quietly(fn, *args) -> None:
    """``fn(*args)`` ahead of a request, its error left to the request (which reports it)."""
    try:
        fn(*args)
    except Exception:  # noqa: BLE001, S110 - the page's own request says what went wrong
        pass


def _jsonable(a):
    """A float array as a list with None for non-finite values."""
    return [None if not np.isfinite(x) else round(float(x), 4) for x in np.asarray(a, float)]


def _jsonable_or_none(a):
    """:func:`_jsonable`, or None for None (a record the build does not have)."""
    return None if a is None else _jsonable(a)


class Build:
    """One build folder: its tables and caches, loaded lazily and dropped after a run.

    Two locks: ``lock`` for the feasibility and the target (fractions of a second), and
    ``viewer_lock`` for the morph viewer's data (seconds on a large build), so that the
    editor's data never waits behind the viewer's being made."""

    def __init__(self, folder: Path):
        self.folder = folder
        self.lock = threading.Lock()
        self.viewer_lock = threading.Lock()
        self._viewer = None
        self._viewer_key = None
        self._viewer_bytes = None
        self._feas = None
        self._target = None       # (the files' stamp, the target)
        self._parts = None        # (the files' stamp, the parts)
        self._prefetch = None     # the thread making the viewer's bytes ahead of the page

    def info(self, i: int) -> dict:
        return {"id": i, "name": self.folder.name, "path": str(self.folder),
                "has_frames": (self.folder / "sim" / "frames.npz").is_file()}

    def forget(self) -> None:
        """Drop the caches (the folder was built again)."""
        with self.lock:
            self._feas = self._target = self._parts = None
        with self.viewer_lock:
            self._viewer = self._viewer_key = None

    def viewer(self) -> dict:
        p = self.folder / "sim" / "frames.npz"
        if not p.is_file():
            raise InputError(f"{p}: no simulation in this build",
                             fix=f"run 'morphshell simulate {self.folder}' or press Run")
        key = (p.stat().st_mtime_ns, (self.folder / "cells.csv").stat().st_mtime_ns)
        with self.viewer_lock:
            if self._viewer_key != key:
                # positions as uint16 over their box (~2 um on a 150 mm shell, as the
                # report's viewer): petal's morph 6.8 MB instead of 12.5 MB of JSON
                self._viewer = morph_viewer(self.folder, max_frames=241, quantise=True)
                self._viewer_key = key
            return self._viewer

    def viewer_body(self, gzipped: bool) -> bytes:
        """The viewer's JSON as bytes, gzip-compressed when ``gzipped`` (kept with the data:
        petal's morph is 6.8 MB of JSON, 3.9 MB compressed; ``docs/results.md``)."""
        data = self.viewer()
        with self.viewer_lock:
            cache = self._viewer_bytes
            if cache is None or cache[0] is not data:
                raw = json.dumps(data, separators=(",", ":")).encode()
                cache = self._viewer_bytes = (data, raw, {})
            if not gzipped:
                return cache[1]
            if "gz" not in cache[2]:
                cache[2]["gz"] = gzip.compress(cache[1], compresslevel=5, mtime=0)
            return cache[2]["gz"]

    def prefetch_viewer(self) -> None:
        """Make the viewer's compressed bytes in a background thread, so that they are ready
        when the page asks for them (once its editor is usable); nothing without a
        simulation or while a thread is at it.  An error is left to the page's own request,
        which reports it."""
        if not (self.folder / "sim" / "frames.npz").is_file():
            return
        with self.lock:
            if self._prefetch is not None and self._prefetch.is_alive():
                return
            t = threading.Thread(target=_quietly, args=(self.viewer_body, True), daemon=True,
                                 name=f"viewer-{self.folder.name}")
            t.start()   # published started: whoever sees it may join it
            self._prefetch = t

    def warm(self) -> None:
        """Make what the page asks for, in the order it asks: the target (the editor's data
        and its feasibility), the parts, then the viewer's bytes (in the background).  The
        studio calls it when it starts, while the browser starts; errors are left to the
        page's requests."""
        _quietly(self.target)
        _quietly(self.parts)
        self.prefetch_viewer()

    def feasibility(self) -> Feasibility:
        with self.lock:
            if self._feas is None:
                self._feas = Feasibility(self.folder)
            return self._feas

    def stencil(self):
        return read_stencil(self.folder / "stencil.obj")

    def landscape(self) -> np.ndarray:
        """(n_vertices,) float, s: the build's own landscape (``time_landscape.csv``)."""
        return read_table(self.folder, "time_landscape")["time_s"]

    def target(self) -> dict:
        """The editor's data: the target stencil, the build's landscape and its hash (a Run's
        base), the cells as programmed and their simulated completion, the feasibility of
        the landscape, the limits and the edit log; kept until one of the files it is made
        from changes (or :meth:`forget`)."""
        key = _stamps(self.folder, _TARGET_FILES)
        with self.lock:
            if self._target is not None and self._target[0] == key:
                return self._target[1]
        out = self._make_target()
        with self.lock:
            self._target = (key, out)
        return out

    def _make_target(self) -> dict:
        V, _, F = self.stencil()
        land = self.landscape()
        cells = read_table(self.folder, "cells")
        ev = self.feasibility().evaluate(land)
        done = None
        if (self.folder / "sim" / "frames.npz").is_file():
            # the completion rule on frames.npz's few arrays it reads (the viewer's t_done,
            # without making the viewer's data: seconds on a large build)
            done = _jsonable(completion_times(self.folder))
        return {"V": np.round(V, 5).reshape(-1).tolist(), "F": F.reshape(-1).tolist(),
                "build": self.folder.name,
                "landscape_sha256": run_base_sha256(self.folder, land),   # a Run's base
                "landscape": [float(x) for x in land],
                "vertex_a": cells["vertex_a"].tolist(), "vertex_b": cells["vertex_b"].tolist(),
                "programmed": {
                    "t_star": _jsonable(cells["t_star_s"]),
                    "clamped": np.asarray(cells["clamped"], int).tolist(),
                    "h_top": _jsonable(cells["thickness_top_mm"]),
                    "h_bottom": _jsonable(cells["thickness_bottom_mm"]),
                    "t_done": done, "t_sd": _jsonable_or_none(
                        predicted_timing_sd(self.folder, len(cells["cell_id"])))},
                "feasibility": self._feas_json(ev),
                "limits": {"max_time_s": LIMITS.max_landscape_s,
                           "max_radius_mm": LIMITS.studio_max_radius_mm},
                "source": read_record(self.folder / LANDSCAPE_SOURCE)}

    @staticmethod
    def _feas_json(ev) -> dict:
        n = len(ev["clamped"])
        n_clamped = int(ev["clamped"].sum())
        return {"t_star": _jsonable(ev["t_star"]), "t_min": _jsonable(ev["t_min"]),
                "t_max": _jsonable(ev["t_max"]), "clamped": ev["clamped"].astype(int).tolist(),
                "side": np.asarray(ev["side"], int).tolist(), "n_clamped": n_clamped,
                "refused": bool(n and n_clamped / n > PROGRAMMING.max_clamped_fraction),
                "max_clamped_fraction": PROGRAMMING.max_clamped_fraction}

    def changed_parts(self, landscape, refine: int) -> float:
        """Fraction of the printable parts a Run of ``landscape`` renders (the others come
        from the part cache): none for the build's own landscape, or for one a build beside
        it was made of already (:meth:`built_before`); with refinement (``refine`` rounds
        > 0) all for any other edit, an upper bound: the refinement moves many cells'
        bracket thickness a little (petal: 256 and 703 of 703 parts rendered again for two
        edits, and 64 for a run of its own landscape; ``docs/results.md``); without it, the
        parts of the bases with a cell whose requested time moved.

        Parameters
        ----------
        landscape : (n_vertices,) float, s
        refine : int -- the build's refinement rounds

        Returns
        -------
        float -- 0 to 1
        """
        moved = self._moved_bases(landscape)
        if moved and self.built_before(landscape) is not None:
            return 0.0
        return 1.0 if moved and refine > 0 else moved

    def built_before(self, landscape) -> Path | None:
        """A build beside this one (``<parent>/*/``) made by a Run of this build with
        ``landscape`` (the same inputs hash, :func:`pysolver.build.rebuild_inputs_hash`):
        the parts it rendered are in the part cache the builds beside each other share.
        None when there is none."""
        own = (read_record(self.folder / "summary.json") or {}).get("inputs_sha256")
        if not own:
            return None
        digest, _ = rebuild_inputs_hash(own, round_sig9(np.asarray(landscape, float)))
        for p in sorted(self.folder.parent.glob("*/summary.json")):
            rec = read_record(p)
            if isinstance(rec, dict) and rec.get("inputs_sha256") == digest:
                return p.parent
        return None

    def _moved_bases(self, landscape) -> float:
        """Fraction of the bases with a cell whose requested time ``landscape`` moves."""
        c = read_table(self.folder, "cells")
        a, b = c["vertex_a"], c["vertex_b"]
        moved = cell_target_times(np.asarray(landscape, float), a, b) != cell_target_times(
            self.landscape(), a, b)
        bases = np.union1d(c["base_a"], c["base_b"])
        hit = np.union1d(c["base_a"][moved], c["base_b"][moved])
        return float(len(hit) / len(bases)) if len(bases) else 0.0

    def n_vertices(self) -> int:
        return len(self.stencil()[0])

    def preview(self, payload) -> dict:
        land = parse_landscape(payload, self.n_vertices())
        t0 = time.perf_counter()
        feas = self._feas_json(self.feasibility().evaluate(land))
        feas["seconds"] = round(time.perf_counter() - t0, 4)
        return {"feasibility": feas}

    def import_csv(self, payload) -> dict:
        """``{"csv": text}`` (an upload: validated, :func:`parse_landscape_csv`) -> the
        landscape and its feasibility; nothing is written."""
        if not isinstance(payload, dict) or set(payload) != {"csv"}:
            raise InputError("the import request must be {'csv': text}",
                             fix="send the CSV file's text as 'csv'")
        land = parse_landscape_csv(payload["csv"], self.n_vertices())
        return {"landscape": [float(x) for x in land],
                "feasibility": self._feas_json(self.feasibility().evaluate(land))}

    def check_run(self, req: dict) -> None:
        """Refuse a Run (:func:`parse_run`'s ``req``) that was not edited from this build's
        current landscape: one landscape, one build.  The base hash binds the build's
        resolved folder (:func:`run_base_sha256`), so two builds of one name (``regular``
        beside another ``regular``) and one landscape are still told apart.

        Raises
        ------
        Stale
            It names another build, or its base is not this build's own landscape (another
            build's, of any name, or this one's before it was built again).
        """
        if req["build"] != self.folder.name:
            raise Stale(f"this Run names build {req['build'][:80]!r} but was sent to build "
                        f"{self.folder.name!r}: nothing was built",
                        fix="select the build in the editor, wait for it to load, then Run")
        if req["base_sha256"] != run_base_sha256(self.folder, self.landscape()):
            raise Stale(f"the edit was not made on the current landscape of build "
                        f"{self.folder.name!r} ({self.folder}) "
                        "(another build's, perhaps one of the same name, or this one's "
                        "before it was built again): nothing was built",
                        fix="load the build again in the editor (select it), then Run; "
                            "export the edit as CSV first to keep it")

    def keyframes(self, payload) -> dict:
        V, _, F = self.stencil()
        b, bc = keyframe_values(parse_keyframes(payload, len(V)))
        land = harmonic_landscape(V, F, b, bc)
        return {"landscape": [float(x) for x in land],
                "feasibility": self._feas_json(self.feasibility().evaluate(land))}

    def results(self) -> dict:
        now = report_figures(self.folder)
        edited = (read_record(self.folder / "summary.json") or {}).get("edited") or {}
        has_report = (self.folder / "report" / "index.html").is_file()
        return {"now": now, "before": edited.get("before") if edited else None,
                "edited": bool(edited), "report": has_report}

    def parts(self) -> dict:
        """:func:`pysolver.simulator.build_parts` (the STLs hashed and read: a fraction of a
        second on petal's 15 MB), kept until a table or a file of ``stl/`` changes."""
        stl = self.folder / "stl"
        names = sorted(p.name for p in stl.iterdir()) if stl.is_dir() else []
        key = (tuple(names), _stamps(self.folder, (*TABLE_FILES, *(f"stl/{n}" for n in names))))
        with self.lock:
            if self._parts is not None and self._parts[0] == key:
                return self._parts[1]
        out = build_parts(self.folder)
        with self.lock:
            self._parts = (key, out)
        return out

    def stl(self, name: str) -> Path:
        listed = {s["name"] for s in self.parts()["stls"]}
        if not STL_NAME.fullmatch(name) or f"stl/{name}" not in listed:
            raise InputError(f"no printable part {name!r} in this build",
                             fix="pick one of the parts listed (stale parts are not served)")
        return self.folder / "stl" / name


__all__ = ["Build", "Stale", "STL_NAME"]
