"""`python -m servodyn.tools.cli`: the `servodyn` command."""

import sys

from . import main

sys.exit(main())
