"""``python -m sb3_marl`` = the ``sb3-marl`` command line (see :mod:`sb3_marl.cli`)."""

import sys

from sb3_marl.cli import main

if __name__ == "__main__":
    sys.exit(main())
