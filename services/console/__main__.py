import sys

from services.console.service import cli

sys.exit(cli())
