import sys

from fitstiff.cli import console

sys.exit(console())
