"""``python -m e2e.bench.real``: see ``e2e.bench.real.run``."""

import sys

from e2e.bench.real.run import main

sys.exit(main())
