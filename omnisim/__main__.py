"""``python -m omnisim`` runs the command line."""

import sys

try:
    from .cli import main
except KeyboardInterrupt:  # interrupted before the command line could install its handler
    print("omnisim: interrupted (rerun the same command to resume)", file=sys.stderr)
    exec("pass")  # clears CPython's unhandled-interrupt mark (see ifmi.runtime.interrupts.report_interrupt)
    sys.exit(130)

sys.exit(main())
