import sys

from services.teacher.service import cli

sys.exit(cli())
