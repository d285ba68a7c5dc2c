"""``python -m pysolver.cli ...``: the same as the ``morphshell`` console script."""

import sys

from . import main

sys.exit(main())
