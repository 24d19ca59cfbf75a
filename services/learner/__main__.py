import sys

from services.learner.service import cli

sys.exit(cli())
