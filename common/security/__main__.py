"""``python -m common.security``: init, router, zenohd-config (see the package docstring)."""
import sys

from common.security.router import main

sys.exit(main())
