import sys

try:
    from hybridsplat.cli import entry
except KeyboardInterrupt:  # Ctrl-C while the command modules are still being imported
    print("hybridsplat: interrupted", file=sys.stderr)
    sys.exit(130)

entry()
