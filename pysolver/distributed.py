"""Run many self-contained tasks on Dask (``dask.distributed``), one result file per task.

Used by ``morphshell tolerance`` (:mod:`pysolver.tolerance`, one simulation per task) and
``morphshell sweep`` (:mod:`pysolver.sweep`, one build per task).

* **Cluster.**  By default a ``LocalCluster`` sized to the machine (one single-threaded
  worker process per core: every task runs its linear algebra on one BLAS thread anyway);
  ``scheduler="tls://host:8786"`` sends the same tasks to an existing cluster
  (``docs/tolerance.md`` shows how to start one on several machines).
* **Self-contained tasks.**  A :class:`Task` is an importable function and its arguments
  (plain data: arrays, numbers, file contents), so any worker on any machine can run it; the
  worker needs the same morphshell installed, not the caller's files.
* **Atomic results, resumable runs.**  The caller (not the worker) writes each result to
  ``<store>/<key>.json`` through a temporary file and a rename as soon as it arrives, together
  with the task's input fingerprint.  A rerun after a crash, a Ctrl-C or a lost worker loads
  the results whose fingerprint matches and computes only the missing ones.  A lost worker's
  tasks are rescheduled by Dask on the others; results do not depend on where they ran.
* **Progress.**  One line to stderr at most every few seconds: tasks done (and loaded from an
  earlier run), failed, ETA, and the Dask dashboard address.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import logging
import os
import re
import shutil
import tempfile
import time
import warnings
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path

from .core.child import safe_path_environ
from .core.inputs import read_input
from .core.progress import duration, say
from .core.records import json_default, json_text
from .core.writes import atomic_write_text
from .errors import InputError
from .params import TOLERANCE_RUN

KEY_RE = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]{0,120}$")
SCHEDULER_RE = re.compile(r"^(tcp|tls|ws|wss|inproc|ucx)://[A-Za-z0-9_.:\[\]/-]{1,200}$")
RESULT_FORMAT = "morphshell.task_result"


def _soft_import_distributed():
    """``distributed`` is a declared dependency; a broken install fails here with the fix."""
    try:
        import distributed  # optional heavy dependency: Dask only for distributed runs
    except ImportError as e:  # pragma: no cover - depends on the environment
        raise InputError(f"dask.distributed is not installed ({e})",
                         fix="pip install 'dask[distributed]' (it is in pyproject.toml)") from None
    return distributed


def fingerprint(*parts) -> str:
    """SHA-256 of a JSON rendering of ``parts`` (sorted keys; bytes hashed by content).

    Parameters
    ----------
    *parts : JSON-able values, ``bytes`` or objects with ``to_dict()``

    Returns
    -------
    str, 64 hex digits
    """
    h = hashlib.sha256()

    def default(o):
        if isinstance(o, bytes):
            return {"sha256": hashlib.sha256(o).hexdigest()}
        if hasattr(o, "to_dict"):
            return o.to_dict()
        return json_default(o)  # numpy values, paths; anything else: TypeError

    for p in parts:
        h.update(json.dumps(p, sort_keys=True, default=default).encode())
        h.update(b"\0")
    return h.hexdigest()


def code_files() -> list:
    """The files whose content :func:`code_fingerprint` hashes: every module of both
    packages, stage subpackages included (``pysolver/**/*.py``, ``sim/**/*.py``), the SCAD
    library (``scad/*.scad``) and the committed model files (``pysolver/data/*.json``)."""
    root = Path(__file__).resolve().parents[1]
    return sorted([*root.glob("pysolver/**/*.py"), *root.glob("sim/**/*.py"),
                   *root.glob("scad/*.scad"), *root.glob("pysolver/data/*.json")])


def code_fingerprint() -> str:
    """SHA-256 of the project's code (:func:`code_files`): a stored result is reused only by
    the same code."""
    root = Path(__file__).resolve().parents[1]
    h = hashlib.sha256()
    for f in code_files():
        h.update(f.relative_to(root).as_posix().encode() + b"\0")
        h.update(hashlib.sha256(f.read_bytes()).digest())
    return h.hexdigest()


@dataclass(frozen=True)
class Task:
    """One unit of work: ``fn(*args)`` on any worker.

    Attributes
    ----------
    key : str
        File-safe name, unique in its run (``[A-Za-z0-9_.-]``, starts alphanumeric).
    fn : callable
        A module-level function of an installed module (pickled by reference).
    args : tuple
        Plain data only (numbers, strings, arrays, bytes, frozen dataclasses of those).
    fingerprint : str
        Hash of everything the result depends on; a stored result is reused only when its
        fingerprint is the same.
    """

    key: str
    fn: Callable
    args: tuple = ()
    fingerprint: str = ""

    def __post_init__(self):
        if not KEY_RE.match(self.key):
            raise InputError(f"task key {self.key!r} is not a file-safe name",
                             fix="use letters, digits, '_', '.', '-' (at most 121 characters)")


class ResultStore:
    """A folder of per-task JSON results, each written atomically.

    Parameters
    ----------
    folder : path-like
        Created when missing.
    """

    def __init__(self, folder):
        self.folder = Path(folder)

    def path(self, key: str) -> Path:
        return self.folder / f"{key}.json"

    def load(self, task: Task):
        """The stored result of ``task`` when its fingerprint matches, else ``None``.

        A damaged or foreign file is treated as missing (and replaced when the task runs).
        """
        p = self.path(task.key)
        try:
            d = json.loads(read_input(p, "task result"))
        except (OSError, ValueError):
            return None
        if (not isinstance(d, dict) or d.get("format") != RESULT_FORMAT
                or d.get("key") != task.key or d.get("fingerprint") != task.fingerprint):
            return None
        return d.get("result")

    def save(self, task: Task, result) -> None:
        atomic_write_text(self.path(task.key), json_text(
            {"format": RESULT_FORMAT, "key": task.key, "fingerprint": task.fingerprint,
             "result": result}, indent=None))


@dataclass
class RunStats:
    """What a :func:`run_tasks` call did.

    Attributes
    ----------
    total, loaded, computed : int
        Tasks, results reused from the store, results computed now.
    failed : dict of str -> str
        Task key -> error message (not stored: a rerun tries them again).
    wall_s : float, s
    workers : int
        Workers of the cluster when the run started.
    dashboard : str or None
        Dask dashboard address.
    """

    total: int = 0
    loaded: int = 0
    computed: int = 0
    failed: dict = field(default_factory=dict)
    wall_s: float = 0.0
    workers: int = 0
    dashboard: str | None = None

    def to_dict(self) -> dict:
        return {"total": self.total, "loaded": self.loaded, "computed": self.computed,
                "failed": dict(self.failed), "wall_s": round(self.wall_s, 3),
                "workers": self.workers, "dashboard": self.dashboard}


def check_scheduler(address) -> str | None:
    """Validate a ``--scheduler`` address (``tls://host:8786``); ``None`` passes."""
    if address is None:
        return None
    a = str(address).strip()
    if not SCHEDULER_RE.match(a):
        raise InputError(f"--scheduler {address!r} is not a Dask scheduler address",
                         fix="use tls://HOST:8786 (the address 'dask scheduler' prints)")
    return a


def check_workers(workers) -> int | None:
    if workers is None:
        return None
    if not isinstance(workers, int) or isinstance(workers, bool) or not 1 <= workers <= 1024:
        raise InputError(f"--workers {workers!r}", fix="use a whole number from 1 to 1024")
    return workers


LOOPBACK = "127.0.0.1"
"""The one interface the local cluster (scheduler, workers, dashboard) listens on."""


def local_security():
    """Dask TLS security with a certificate made for this run only (mutual TLS).

    The scheduler and the workers accept only peers that present this certificate, which
    lives in this process's memory (and its workers'): another local user cannot submit
    work to the cluster, nor read what flows in it.

    Raises
    ------
    InputError
        The ``cryptography`` package (a declared dependency) is missing.
    """
    try:
        from distributed.security import Security  # heavy: Dask only for distributed runs

        return Security.temporary()
    except ImportError as e:  # Security.temporary needs cryptography
        raise InputError(f"cannot make the local cluster's TLS certificate ({e})",
                         fix="reinstall the environment: make venv") from None


class PlainSchedulerWarning(UserWarning):
    """A ``--scheduler`` without encryption or authentication."""


def _warn_plain(scheduler: str) -> None:
    if scheduler.startswith(("tcp://", "ws://")):
        warnings.warn(f"{scheduler} is plain {scheduler.split(':')[0]}: anyone who can reach it "
                      "can submit code to its workers, and the designs travel unencrypted. "
                      "Use a tls:// scheduler and give its certificates in Dask's "
                      "configuration (distributed.comm.tls.*; docs/tolerance.md).",
                      PlainSchedulerWarning, stacklevel=3)


@contextlib.contextmanager
def dask_client(scheduler: str | None = None, workers: int | None = None,
                progress: bool = True, dashboard: bool = False):
    """A ``distributed.Client``: of an existing cluster, or of a new ``LocalCluster``.

    The local cluster listens on the loopback interface only (:data:`LOOPBACK`), speaks TLS
    with a certificate made for this run (:func:`local_security`), serves no web pages
    (no dashboard, no HTTP routes) unless ``dashboard`` is asked for, and keeps its scratch
    files in a private folder made for the run (mode 0700, a random name; removed after),
    never in Dask's fixed ``dask-scratch-space`` of the shared temporary folder, which
    another user could make first.

    Parameters
    ----------
    scheduler : str, optional
        ``tls://host:port`` (or ``tcp://``, with a warning) of a running ``dask scheduler``;
        credentials come from Dask's configuration (``distributed.comm.tls.*``).
    workers : int, optional
        Worker processes of the local cluster (default: one per core); ignored with
        ``scheduler``.
    progress : bool
        Print the cluster (and its dashboard address) to stderr.
    dashboard : bool
        Serve the local cluster's dashboard, on the loopback interface.

    Yields
    ------
    distributed.Client
    """
    distributed = _soft_import_distributed()
    import dask  # (with distributed)

    scheduler = check_scheduler(scheduler)
    workers = check_workers(workers)
    with contextlib.ExitStack() as stack:
        if scheduler is not None:
            client = _remote_client(distributed, scheduler)
        else:
            cluster, security = stack.enter_context(_local_cluster(
                distributed, dask, workers or os.cpu_count() or 1, dashboard))
            client = distributed.Client(cluster, security=security)
        stack.callback(client.close)    # (before the cluster's close: last in, first out)
        if progress:
            nw = len(client.scheduler_info().get("workers", {}))
            where = scheduler or f"local cluster on {LOOPBACK} (TLS)"
            dash = f", dashboard {client.dashboard_link}" if (dashboard or scheduler) else ""
            say("dask", "", f"{where}, {nw} worker(s){dash}")
        yield client


def _remote_client(distributed, scheduler: str):
    """A ``distributed.Client`` of the running scheduler at ``scheduler``."""
    _warn_plain(scheduler)
    try:
        return distributed.Client(scheduler, timeout="20s")
    except OSError as e:
        raise InputError(f"cannot reach the Dask scheduler at {scheduler} ({e})",
                         fix="start it with 'dask scheduler' and check the address, the "
                             "firewall and the TLS settings (docs/tolerance.md)") from None


@contextlib.contextmanager
def _local_cluster(distributed, dask, n: int, dashboard: bool):
    """A running ``LocalCluster`` of ``n`` worker processes, and its ``Security``, for the
    block (see :func:`dask_client`); closed after it, and its scratch folder removed (also
    when the cluster fails to start).

    Its workers are Python processes that multiprocessing starts ("spawn"), not through
    :func:`pysolver.core.child.python_argv`: the cluster lives inside
    :func:`pysolver.core.child.safe_path_environ`, so no worker (a restarted one included) puts
    the working directory on its module path.

    Yields
    ------
    (distributed.LocalCluster, distributed.Security)
    """
    security = local_security()
    scratch = tempfile.mkdtemp(prefix="morphshell-dask-")   # 0700, a random name
    config = {"temporary-directory": scratch}
    if not dashboard:
        config.update({"distributed.scheduler.http.routes": [],
                       "distributed.worker.http.routes": []})
    try:   # the scratch folder goes also when the cluster fails to start
        with safe_path_environ():
            with dask.config.set(config):
                cluster = distributed.LocalCluster(
                    n_workers=n, threads_per_worker=1, processes=True, host=LOOPBACK,
                    protocol="tls", security=security, local_directory=scratch,
                    dashboard_address=f"{LOOPBACK}:0" if dashboard else None,
                    silence_logs=logging.ERROR)
            try:
                yield cluster, security
            finally:
                cluster.close()
    finally:
        shutil.rmtree(scratch, ignore_errors=True)


def run_tasks(tasks: Iterable[Task], store: ResultStore, *, client=None,
              scheduler: str | None = None, workers: int | None = None,
              progress: bool = True, label: str = "tasks",
              on_result: Callable | None = None,
              dashboard: bool = False) -> tuple[dict, RunStats]:
    """Run the tasks whose results are not stored yet; store each result as it arrives.

    Parameters
    ----------
    tasks : iterable of Task
        Unique keys.
    store : ResultStore
    client : distributed.Client, optional
        Use this client (tests); else one is made by :func:`dask_client`.
    scheduler, workers, dashboard : see :func:`dask_client`
    progress : bool
    label : str
        Stage of the progress lines (``[label] k/n done ... ETA``, :mod:`pysolver.core.progress`).
    on_result : callable, optional
        ``on_result(key, result)`` after each computed result is stored (tests use it to
        kill a worker mid-run).

    Returns
    -------
    results : dict of str -> result
        Every task that has a result (loaded or computed), by key.
    stats : RunStats
    """
    tasks = list(tasks)
    keys = [t.key for t in tasks]
    if len(set(keys)) != len(keys):
        raise InputError("duplicate task keys", fix="give every task its own key")
    t_start = time.perf_counter()
    stats = RunStats(total=len(tasks))
    results = {}
    todo = []
    for t in tasks:
        r = store.load(t)
        if r is None:
            todo.append(t)
        else:
            results[t.key] = r
    stats.loaded = len(results)
    say(label, "", f"{stats.loaded}/{stats.total} result(s) from an earlier run in "
        f"{store.folder}", progress and stats.loaded > 0)
    if todo:
        with contextlib.ExitStack() as stack:
            if client is None:
                client = stack.enter_context(dask_client(scheduler, workers, progress,
                                                         dashboard=dashboard))
            if dashboard or scheduler is not None:
                stats.dashboard = client.dashboard_link
            _compute(client, todo, store, results, stats, progress, label, on_result,
                     t_start)
    stats.wall_s = time.perf_counter() - t_start
    say(label, "", f"{stats.total - len(stats.failed)}/{stats.total} done ({stats.computed} "
        f"computed, {stats.loaded} loaded), {len(stats.failed)} failed, "
        f"{duration(stats.wall_s)}", progress)
    return {k: results[k] for k in keys if k in results}, stats


def _compute(client, todo, store, results, stats, progress, label, on_result, t_start):
    distributed = _soft_import_distributed()
    stats.workers = len(client.scheduler_info().get("workers", {}))
    by_key = {}
    futures = []
    for t in todo:
        dkey = f"{label}-{t.key}-{t.fingerprint[:12]}"
        fut = client.submit(t.fn, *t.args, key=dkey, pure=False)
        by_key[fut.key] = t
        futures.append(fut)
    last = 0.0
    t_run = time.perf_counter()
    n = len(todo)
    done = 0
    for fut in distributed.as_completed(futures):
        t = by_key[fut.key]
        if fut.status == "finished":
            try:
                res = fut.result()
            except Exception as e:  # noqa: BLE001 - a lost result counts as a failure
                stats.failed[t.key] = f"{type(e).__name__}: {e}"
            else:
                store.save(t, res)
                results[t.key] = res
                stats.computed += 1
                if on_result is not None:
                    on_result(t.key, res)
        else:
            try:  # an error, or a cancelled task (the cluster went away)
                exc = fut.exception()
            except Exception as e:  # noqa: BLE001
                exc = e
            stats.failed[t.key] = f"{type(exc).__name__}: {exc}"
            say(label, "", f"task {t.key} failed: {stats.failed[t.key]}", progress)
        fut.release()
        done += 1
        now = time.perf_counter()
        if progress and (now - last >= TOLERANCE_RUN.progress_every_s or done == n):
            last = now
            rate = (now - t_run) / max(stats.computed, 1)
            eta = rate * (n - done) if stats.computed else float("nan")
            say(label, "", f"{stats.loaded + done}/{stats.total} done, {len(stats.failed)} "
                f"failed  ETA {duration(eta)}"
                + (f"  (dashboard {stats.dashboard})" if stats.dashboard else ""))


__all__ = ["Task", "ResultStore", "RunStats", "run_tasks", "dask_client", "fingerprint",
           "code_files", "code_fingerprint",
           "check_scheduler", "check_workers"]
