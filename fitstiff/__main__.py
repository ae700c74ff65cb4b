import sys

from fitstiff.cli import main

sys.exit(main())
