import sys

from services.learner.start import cli

sys.exit(cli())
