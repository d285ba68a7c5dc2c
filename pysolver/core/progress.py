"""Progress lines on stderr, in one style for every stage.

Every line reads ``[<stage>] <subject>: <message>``: ``stage`` is the pipeline stage or tool
speaking (``build``, ``design``, ``program``, ``simulate``, ``refine``, ``render``,
``report``, ...), ``subject`` what it works on (usually the design folder's name).  Counted
work puts ``k/n`` first in the message and ends the line with ``ETA`` and the time left
(:func:`duration`) once a step has been timed::

    [build] petal: simulate ...
    [simulate] petal: 12/241 t=   5.5 s  newton   4  |g| 3.1e-07 N   0.21 s  ETA 48 s
    [render] petal: 40/118 parts (fast)  ETA 31 s
    [report] petal: 3/10 timing (+0.1 s)

Each line can also go out as a structured event, one JSON object per line, to a stream set
by :func:`emit_events` (the studio's Run sends them on the child's stdout and its progress bar
reads those, not the text)::

    {"event": "stage", "stage": "build", "subject": "petal", "starts": "simulate", "text": ...}
    {"event": "line", "stage": "simulate", "subject": "petal", "k": 12, "n": 241, "text": ...}

Nothing here decides *whether* to print: every function takes ``enabled`` (the stages'
``progress`` option).
"""

from __future__ import annotations

import json
import sys
import time

ETA_WINDOW = 20
"""Steps whose mean duration predicts the remaining time."""


def duration(s: float) -> str:
    """Seconds in words for an ETA: ``48 s``, ``2m05s``, ``1h02m`` (``?`` when unknown)."""
    if s is None or s != s or s in (float("inf"), float("-inf")):
        return "?"
    s = int(round(s))
    if s >= 3600:
        return f"{s // 3600}h{s % 3600 // 60:02d}m"
    return f"{s // 60}m{s % 60:02d}s" if s >= 60 else f"{s} s"


def line(stage: str, subject: str, message: str) -> str:
    """One progress line, without printing it: ``[stage] subject: message``."""
    return f"[{stage}] {subject}: {message}" if subject else f"[{stage}] {message}"


_EVENTS = None
"""The text stream structured events go to (:func:`emit_events`), or None."""


def emit_events(stream) -> None:
    """Also write every progress line as a JSON object (one per line) on ``stream``; None
    stops.  For a child process whose parent reads its progress (the studio's Run)."""
    global _EVENTS
    _EVENTS = stream


def say(stage: str, subject: str, message: str, enabled: bool = True, *,
        k: int | None = None, n: int | None = None, starts: str | None = None) -> None:
    """Print one progress line (:func:`line`) on stderr when ``enabled``, and its event
    (:func:`emit_events`): with ``k`` of ``n`` steps done, or ``starts``, the name of the
    stage a build starts."""
    if not enabled:
        return
    text = line(stage, subject, message)
    print(text, file=sys.stderr, flush=True)
    if _EVENTS is not None:
        ev = {"event": "stage" if starts else "line", "stage": stage, "subject": subject,
              "text": text}
        if starts:
            ev["starts"] = starts
        if k is not None and n is not None:
            ev.update(k=int(k), n=int(n))
        _EVENTS.write(json.dumps(ev) + "\n")
        _EVENTS.flush()


class Steps:
    """Counted work with an ETA: ``[stage] subject: k/n message  ETA s``.

    Parameters
    ----------
    stage, subject : str
        The line's prefix (:func:`line`).
    total : int
        Number of steps ``n``.
    enabled : bool
        Print at all (the stage's ``progress`` option).
    every_s : float, s
        Print at most one line per ``every_s`` seconds (the last step always prints);
        0 prints every step.
    laps : bool
        Add the seconds since the previous step, ``(+1.2 s)``, instead of an ETA.
    """

    def __init__(self, stage: str, subject: str, total: int, *, enabled: bool = True,
                 every_s: float = 0.0, laps: bool = False):
        self.stage, self.subject, self.total = stage, subject, int(total)
        self.enabled, self.every_s, self.laps = enabled, float(every_s), laps
        self.k = 0
        self.durations: list[float] = []
        self.t_last = self.t_printed = time.perf_counter()

    def eta_s(self) -> float | None:
        """Seconds left at the mean of the last :data:`ETA_WINDOW` steps (None before one)."""
        if not self.durations:
            return None
        recent = self.durations[-ETA_WINDOW:]
        return sum(recent) / len(recent) * max(self.total - self.k, 0)

    def step(self, message: str = "", *, k: int | None = None) -> float:
        """Count one step (or set the count to ``k``) and print its line.

        Returns
        -------
        float, s
            Seconds since the previous step.
        """
        now = time.perf_counter()
        lap = now - self.t_last
        self.t_last = now
        self.k = self.k + 1 if k is None else int(k)
        self.durations.append(lap)
        due = now - self.t_printed >= self.every_s or self.k >= self.total
        if self.enabled and due:
            self.t_printed = now
            if self.laps:
                tail = f" (+{lap:.1f} s)"
            else:
                eta = self.eta_s()
                tail = "" if eta is None else f"  ETA {duration(eta)}"
            text = f"{self.k}/{self.total}" + (f" {message}" if message else "") + tail
            say(self.stage, self.subject, text, k=self.k, n=self.total)
        return lap


class Clock:
    """Seconds per named step of one stage, each printed as it ends:
    ``[stage] subject: name  0.52 s (total 3.1 s)``.

    Attributes
    ----------
    t : dict
        ``{name: seconds}`` (rounded to 0.1 ms), the stage's ``timings_s``.
    """

    def __init__(self, progress: bool, subject: str, stage: str = "design"):
        self.t: dict[str, float] = {}
        self.progress, self.subject, self.stage = progress, subject, stage
        self._t0 = self._start = time.perf_counter()

    def step(self, name: str) -> None:
        """End the step ``name`` (the time since the previous one)."""
        now = time.perf_counter()
        self.t[name] = round(now - self._t0, 4)
        self._t0 = now
        say(self.stage, self.subject, f"{name:<10s} {self.t[name]:7.2f} s "
            f"(total {now - self._start:6.1f} s)", self.progress)


__all__ = ["duration", "line", "say", "emit_events", "Steps", "Clock", "ETA_WINDOW"]
