"""`python -m fogfleet ...` is the `fogfleet` command (`python -m fogfleet run`: the operator)."""

from __future__ import annotations

import sys

from fogfleet.commandline.entry import main

if __name__ == "__main__":
    sys.exit(main())
