"""``python -m e2e.realbench``: see ``e2e.realbench.run``."""

import sys

from e2e.realbench.run import main

sys.exit(main())
