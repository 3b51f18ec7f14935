"""`python -m sim.cli`: the `pixelswarm` command."""

import sys

from sim.cli.main import main

sys.exit(main())
