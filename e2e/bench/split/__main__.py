"""``python -m e2e.bench.split``: see ``e2e.bench.split.run``."""

import sys

from e2e.bench.split.run import main

sys.exit(main())
