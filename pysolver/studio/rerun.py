"""The studio's *Run*, in its own process: a build of an edited time landscape.

    python -m pysolver.studio.rerun < request.json

The request (stdin, JSON) is ``{"folder": path, "landscape": [s per stencil vertex],
"source": {...}, "out": path (optional: a new build beside the original)}``;
:func:`pysolver.build.rebuild` runs the stages after the design stage with the build's own
options and replaces the folder (or writes ``out``) only when all have finished.  Its
progress lines go to stderr, and as JSON lines to stdout (:func:`pysolver.core.progress.
emit_events`: the studio's progress bar reads those).  Exit codes as the
command line: 0 done, 3 done with a FAIL verdict, 2 bad input (nothing saved), 1 a bug.
"""

from __future__ import annotations

import json
import sys
import traceback

from ..build import rebuild
from ..core.progress import emit_events
from ..errors import EXIT_BAD_INPUT, EXIT_INTERNAL, MorphshellError, environment_message


def main() -> int:
    emit_events(sys.stdout)   # the studio reads the progress as JSON lines on stdout
    try:
        return _run()
    finally:
        emit_events(None)     # (called in-process, it must not leave its stream behind)


def _run() -> int:
    try:
        req = json.loads(sys.stdin.read())
        summary = rebuild(req["folder"], req["landscape"], source=req.get("source"),
                          out=req.get("out"))
    except MorphshellError as e:
        print(f"morphshell studio run: error: {e}", file=sys.stderr, flush=True)
        return e.exit_code
    except Exception as e:  # a bug: the traceback goes to the studio's log
        env = environment_message(e, "studio run")
        if env is not None:   # a full disk...: named, with the fix
            print(env, file=sys.stderr, flush=True)
            return EXIT_BAD_INPUT
        traceback.print_exc()
        print(f"morphshell studio run: internal error ({type(e).__name__}: {e})",
              file=sys.stderr, flush=True)
        return EXIT_INTERNAL
    return int(summary.get("exit_code", 0))


__all__ = ["main"]

if __name__ == "__main__":
    sys.exit(main())
