import sys

from ifmi.cli import main

sys.exit(main())
