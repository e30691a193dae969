"""``python -m vitaplace.engine.cli``: the ``vitaplace`` command line without its script."""

import sys

from vitaplace.engine.cli.main import main

sys.exit(main())
