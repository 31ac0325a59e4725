"""``python -m fogfleet.commandline.kubectl``: the same as the ``kubectl-fogfleet`` command."""

from __future__ import annotations

import sys

from fogfleet.commandline.kubectl.cli import main

if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
