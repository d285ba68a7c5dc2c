"""The studio's one job, a *Run* (a build again, or into a new build beside it), in a child
process (``python -m pysolver.studio.rerun``): its progress events read into one progress
bar over every stage, its ETA, its timeout and its error message (:class:`Job`)."""

from __future__ import annotations

import json
import subprocess
import threading
import time
from pathlib import Path

from ..build import rebuild_options
from ..core.child import python_argv
from ..errors import MorphshellError
from ..params import LIMITS
from ..stages import STAGES
from .builds import Build


class Busy(MorphshellError):
    """A job is running: the request would change what it is working on (HTTP 409)."""


class Job:
    """The one job (a rebuild) running in a subprocess; its progress events (JSON lines on
    its stdout, :func:`pysolver.core.progress.emit_events`) drive one progress bar over every
    stage, weighted by the stage times of the build being run again; its stderr is kept
    (the last lines) for the error message."""

    DEFAULT_S = {"start": 4.0, "program": 3.0, "simulate": 20.0, "simulate_contact": 20.0,
                 "refine": 25.0, "render": 40.0, "report": 10.0}
    """Expected seconds of a stage the build did not time (its own times come first);
    ``start`` is the subprocess loading the stages."""

    def __init__(self):
        self.lock = threading.Lock()
        self.state = {"state": "idle", "progress": 0.0, "message": "", "build": None,
                      "error": None, "stage": None, "eta_s": None}
        self.on_done = None

    def snapshot(self) -> dict:
        with self.lock:
            return json.loads(json.dumps(self.state))

    def running(self) -> bool:
        with self.lock:
            return self.state["state"] == "running"

    def start(self, build: Build, index: int, land, edits, *, out: Path | None = None,
              on_done=None) -> None:
        """Start a rebuild of ``build`` with landscape ``land`` (validated) and its edit log;
        into the new folder ``out`` (a variant) when given, ``on_done(out)`` called once it
        is complete.

        Raises
        ------
        Busy
            A job is already running (this build's or another's).
        """
        summ, opts = rebuild_options(build.folder)   # InputError: not a build, nothing run
        # the stages a rebuild runs, as it decides (pysolver.stages.STAGES after the design)
        plan = ["start"] + [s.name for s in STAGES[1:] if s.wanted(opts)]
        expect = expected_seconds(summ, self.DEFAULT_S, build.changed_parts(land, opts.refine))
        with self.lock:
            if self.state["state"] == "running":
                raise Busy("a run is already going on"
                           + (" (this build)" if self.state["build"] == index else
                              f" (build {self.state['build']})"),
                           fix="wait for it to finish (see the progress bar), then run again")
            self.state = {"state": "running", "progress": 0.0, "message": "starting",
                          "build": index, "error": None, "stage": None, "plan": plan,
                          "eta_s": round(sum(expect[s] for s in plan), 1),
                          "started": time.time(), "log": [],
                          "variant": None if out is None else out.name}
        req = json.dumps({"folder": str(build.folder), "landscape": [float(x) for x in land],
                          "source": {"edits": edits},
                          **({} if out is None else {"out": str(out)})})
        self.on_done = (lambda: on_done(out)) if out is not None and on_done else None
        threading.Thread(target=self._run, args=(build, req, plan, expect),
                         daemon=True).start()

    def _run(self, build: Build, req: str, plan: list, expect: dict):
        cmd = python_argv("pysolver.studio.rerun")
        done_s = 0.0           # expected seconds of the finished stages
        actual: dict = {}      # seconds the finished stages took in this run
        stage, t_stage, frac = "start", time.time(), 0.0
        tail: list[str] = []
        t0 = time.time()
        proc, ticker, timed_out = None, threading.Event(), threading.Event()
        try:
            proc = subprocess.Popen(cmd, stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                    stderr=subprocess.PIPE, text=True)
            drain = threading.Thread(target=_keep_tail, args=(proc.stderr, tail), daemon=True)
            drain.start()

            def tick():   # the bar moves between progress lines too (time / expected time)
                while not ticker.wait(0.5):
                    if time.time() - t0 > LIMITS.studio_job_timeout_s:   # even when silent
                        timed_out.set()
                        proc.kill()
                        return
                    self._progress(plan, expect, (done_s, actual), stage, t_stage, frac,
                                   None)

            threading.Thread(target=tick, daemon=True).start()
            proc.stdin.write(req)
            proc.stdin.close()
            for raw in proc.stdout:
                ev = progress_event(raw)
                if ev is None:        # not an event (the verdict printed on stdout)
                    continue
                if ev.get("starts") in self.DEFAULT_S:
                    done_s += expect[stage]
                    actual[stage] = time.time() - t_stage
                    stage, t_stage, frac = ev["starts"], time.time(), 0.0
                    if stage not in plan:     # contact switched on: one more simulation
                        plan.insert(plan.index("report") if "report" in plan else len(plan),
                                    stage)
                elif stage != "start" and "k" in ev and (stage != "refine"
                                                         or ev["stage"] == "refine"):
                    frac = max(frac, min(ev["k"] / max(ev["n"], 1), 1.0))
                self._progress(plan, expect, (done_s, actual), stage, t_stage, frac,
                               ev["text"])
            rc = proc.wait()
            ticker.set()
            drain.join(10)
            if timed_out.is_set():
                raise MorphshellError(f"the run took longer than "
                                      f"{LIMITS.studio_job_timeout_s:g} s (stage {stage}) and "
                                      "was stopped; nothing of this edit was saved")
            build.forget()
            if rc in (0, 3) and self.on_done is not None:
                self.on_done()
            if rc not in (0, 3):   # 3 = the report's FAIL verdict: the build is complete
                msg = [t for t in tail if "error:" in t or t.startswith("  Fix:")] or tail[-3:]
                raise MorphshellError(" / ".join(msg).replace("morphshell studio run: ", "")
                                      + "\nNothing of this edit was saved: the build is as "
                                        "it was, and the edit is still in the editor.")
            self._set(state="done", progress=1.0, eta_s=0.0, message="done", stage=None,
                      seconds=round(time.time() - t0, 1))
        except Exception as e:  # noqa: BLE001 - reported to the browser, not raised
            if proc is not None and proc.poll() is None:   # no child left building behind
                proc.kill()                                 # a job that says it failed
                proc.wait()
            self._set(state="error", error=str(e), message="failed", eta_s=None)
        finally:
            ticker.set()

    def _progress(self, plan, expect, done, stage, t_stage, frac, line):
        done_s, actual = done
        total = sum(expect[s] for s in plan)
        now = time.time()
        with self.lock:
            if self.state["state"] != "running":
                return
            if stage is not None:
                spent = now - t_stage
                # within a stage: its own count when it prints one, else the time it has
                # taken of the time it took in the build (never past 95 % on time alone); a
                # stage expected to take no time (a render whose parts all come from the
                # cache, its fixed work rounded away) moves on its own count only
                f = max(frac, min(spent / expect[stage], 0.95)) if expect[stage] > 0 else frac
                p = (done_s + f * expect[stage]) / total
                self.state["progress"] = round(max(self.state["progress"], min(p, 0.999)), 4)
                self.state["stage"] = stage
                self.state["eta_s"] = eta_seconds(plan, expect, actual, stage, spent, frac)
            if line is not None:
                self.state["message"] = line[-200:]
                self.state["log"] = (self.state["log"] + [line[-200:]])[-12:]

    def _set(self, **kw):
        with self.lock:
            self.state.update(kw)


RENDER_PART_S = 0.15
"""Expected wall seconds per part the render stage renders, when the build's own record
rendered none (all its parts came from the cache): petal's fast renderer on 2 cores took
0.137 s (``docs/results.md``)."""


def expected_seconds(summary: dict, defaults: dict, changed: float) -> dict:
    """Expected seconds of each stage of a Run of a build, from what that Run will do.

    Every stage takes the time it took in the build (``summary["timings_s"]``; ``defaults``
    for one the build did not time) but the render: a part whose file the Run leaves as it
    was comes from the part cache, so the render takes its own fixed work (the part files,
    each layer's union, the export: its time less the parts' rendering) plus the rendering
    of the changed parts only, at the build's seconds per part rendered
    (:data:`RENDER_PART_S` when the build rendered none).  (It supposes the cache still
    holds the build's own parts, as the build left it.)

    Parameters
    ----------
    summary : dict -- the build's ``summary.json``
    defaults : dict str -> float, s -- every stage's time when the build has none
    changed : float -- fraction (0-1) of the parts whose files the Run changes
        (:meth:`pysolver.studio.builds.Build.changed_parts`)

    Returns
    -------
    dict str -> float, s -- the keys of ``defaults``
    """
    times = summary.get("timings_s") or {}
    expect = {s: float(times.get(s) or defaults[s]) for s in defaults}
    rec = (summary.get("stages") or {}).get("render") or {}
    tm = rec.get("timings_s") or {}
    parts, rendered = rec.get("parts"), rec.get("rendered")
    if times.get("render") and isinstance(parts, int) and isinstance(rendered, int) and \
            isinstance(tm.get("openscad"), (int, float)):
        own = float(tm["openscad"]) if rendered else 0.0   # the parts' rendering in the build
        per_part = own / rendered if rendered else RENDER_PART_S
        fixed = max(float(times["render"]) - own, 0.0)
        expect["render"] = fixed + min(max(changed, 0.0), 1.0) * parts * per_part
    return expect


def progress_event(raw: str) -> dict | None:
    """One line of a Run's stdout as a progress event (:func:`pysolver.core.progress.say`), or
    None when it is not one: ``event`` ("stage" or "line"), ``stage``, ``text`` (str),
    ``starts`` (str, a stage event), ``k`` and ``n`` (whole numbers, ``n >= 1``) or neither.
    """
    try:
        ev = json.loads(raw)
    except ValueError:
        return None
    if not isinstance(ev, dict) or ev.get("event") not in ("stage", "line") or not all(
            isinstance(ev.get(key), str) for key in ("stage", "text")):
        return None
    if ev["event"] == "stage" and not isinstance(ev.get("starts"), str):
        return None
    if ("k" in ev or "n" in ev) and not (
            isinstance(ev.get("k"), int) and isinstance(ev.get("n"), int) and ev["n"] >= 1):
        return None
    ev["text"] = ev["text"][-200:]
    return ev


def _keep_tail(stream, tail: list, keep: int = 40) -> None:
    """Read ``stream`` to its end, keeping its last ``keep`` lines in ``tail``."""
    for line in stream:
        tail.append(line.rstrip())
        del tail[:-keep]


PACE_PRIOR_S = 30.0
"""Seconds of expected stage time at pace 1 that a run's measured pace is pooled with
(:func:`eta_seconds`): the pace of a run's first short stages moves the ETA little, that of
its long ones much."""


def eta_seconds(plan, expect, actual, stage, spent, frac) -> float:
    """Seconds a run has left: the rest of the stage running now and the stages after it,
    each at the build's own time scaled by this run's pace.

    Parameters
    ----------
    plan : list of str -- the stages in order
    expect : dict str -> float, s -- each stage's time in the build being run again
    actual : dict str -> float, s -- the finished stages' times in this run
    stage : str -- the stage running now
    spent : float, s -- time in it so far
    frac : float -- its own count (0 when it prints none)

    Returns
    -------
    float, s
        ``pace = (sum(actual) + P) / (sum(expect) + P)`` over the finished stages but the
        start, ``P`` = :data:`PACE_PRIOR_S` (1 before one has finished, near 1 while only
        short stages have: a 2 s stage taking 6 s on a busy machine said little of the
        rest, and made a 2 min run's ETA 6.5 min; kept within 0.25-4); the stage running
        now has left ``spent (1 - frac) / frac`` once its count is past 5 %, else its paced
        time less ``spent`` (never below 0); each later stage its paced time.
    """
    done = [s for s in actual if s != "start" and s in expect]
    pace = ((sum(actual[s] for s in done) + PACE_PRIOR_S)
            / (sum(expect[s] for s in done) + PACE_PRIOR_S))
    pace = min(max(pace, 0.25), 4.0)
    if frac > 0.05:
        now_left = spent * (1 - frac) / frac
    else:
        now_left = max(expect[stage] * pace - spent, 0.0)
    later = plan[plan.index(stage) + 1:] if stage in plan else []
    return round(now_left + pace * sum(expect[s] for s in later), 1)


__all__ = ["Job", "Busy", "progress_event", "eta_seconds", "expected_seconds", "RENDER_PART_S",
           "PACE_PRIOR_S"]
