import sys

from services.recorder.service import cli

sys.exit(cli())
