"""The command line and environment of every child Python interpreter morphshell starts.

A child started as ``python -m module`` or ``python -c code`` puts the working directory
first on its module path, so a ``pyvista.py`` or a ``pysolver/__init__.py`` lying where
morphshell was started would run as the user (``docs/threat-model.md``, "Child
processes").  The rule, for every child Python, with no exception:

* **Started by morphshell**: through :func:`python_argv`, the one way to build its command
  line.  The interpreter runs isolated (``-I``: no working directory, no script folder, no
  ``PYTHON*`` variables, no user site folder on its path), and a two-line bootstrap appends
  exactly one folder, the one this package was imported from, when it is not on the path
  already (so a child runs the same morphshell as its parent, also from a source checkout,
  and nothing in it shadows the standard library), before it runs the module or the code.
* **Started by a library** (Dask's worker processes, which multiprocessing starts by
  "spawn" as ``python -B -c 'from multiprocessing.spawn import ...'``, a command line
  morphshell does not write): inside :func:`safe_path_environ`, which sets
  ``PYTHONSAFEPATH=1`` in the environment the children inherit, so that Python (3.11 and
  later) puts no working directory or script folder on their path.  The one place that
  starts such children (``distributed._local_cluster``) holds it for the children's whole
  life, restarts included.
"""

from __future__ import annotations

import contextlib
import os
import sys
from pathlib import Path

PACKAGE_ROOT = str(Path(__file__).resolve().parents[2])
"""The folder holding the ``pysolver`` and ``sim`` packages this process imported."""


def python_argv(module: str | None = None, *, code: str | None = None) -> list[str]:
    """The argv of a child Python that runs ``module`` (as ``python -m``) or ``code`` (as
    ``python -c``) with only the interpreter's own paths and :data:`PACKAGE_ROOT` (after
    them) on its module path.

    Parameters
    ----------
    module : str, optional
        Dotted name of a module of this project to run as ``__main__``.
    code : str, optional
        Python source to run instead (a probe).  Exactly one of the two is given.

    Returns
    -------
    list of str
        ``[sys.executable, "-I", "-c", bootstrap]``; pass it to :mod:`subprocess` as is
        (no shell).

    Raises
    ------
    ValueError
        Neither or both of ``module`` and ``code``, or a module name that is not a dotted
        identifier.
    """
    if (module is None) == (code is None):
        raise ValueError("give exactly one of module and code")
    if module is not None and not all(p.isidentifier() for p in module.split(".")):
        raise ValueError(f"{module!r} is not a dotted module name")
    boot = (f"import sys\nif {PACKAGE_ROOT!r} not in sys.path: "
            f"sys.path.append({PACKAGE_ROOT!r})\n")
    if module is not None:
        boot += f"import runpy; runpy.run_module({module!r}, run_name='__main__', " \
                "alter_sys=True)\n"
    else:
        boot += code
    return [sys.executable, "-I", "-c", boot]


SAFE_PATH = {"PYTHONSAFEPATH": "1"}
"""The environment variable that keeps a Python started by a library (not through
:func:`python_argv`) from putting its working directory on its path."""


@contextlib.contextmanager
def safe_path_environ():
    """Set :data:`SAFE_PATH` in this process's environment while the block runs, for the
    child Pythons a library starts in it (module docstring); the former value is put back
    after.

    Yields
    ------
    None
    """
    before = {k: os.environ.get(k) for k in SAFE_PATH}
    os.environ.update(SAFE_PATH)
    try:
        yield
    finally:
        for k, v in before.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


__all__ = ["PACKAGE_ROOT", "SAFE_PATH", "python_argv", "safe_path_environ"]
