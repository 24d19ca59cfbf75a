import sys

from services.foxglove.service import cli

sys.exit(cli())
