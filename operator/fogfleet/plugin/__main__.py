"""``python -m fogfleet.plugin``: the same as the ``kubectl-fogfleet`` command."""

from __future__ import annotations

import sys

from fogfleet.plugin.cli import main

if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
