"""`python -m jaxmpm`: the jaxmpm command line (see jaxmpm.cli)."""

import sys

from jaxmpm.cli import main

sys.exit(main())
