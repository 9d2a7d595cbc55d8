"""``python -m omnisim`` runs the command line."""

import sys

try:
    from .cli import main
except KeyboardInterrupt:  # interrupted before the command line could install its handler
    print("omnisim: interrupted", file=sys.stderr)
    sys.exit(130)

sys.exit(main())
