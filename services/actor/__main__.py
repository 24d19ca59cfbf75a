import sys

from services.actor.service import cli

sys.exit(cli())
