import sys

from services.replay.service import cli

sys.exit(cli())
