import sys

try:
    from fitstiff.cli import console
except KeyboardInterrupt:               # Ctrl-C while Python imports the command line
    sys.stderr.write("fitstiff: interrupted by SIGINT; nothing was written\n")
    sys.exit(130)

sys.exit(console())
