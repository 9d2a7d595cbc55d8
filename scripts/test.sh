#!/usr/bin/env bash
# Set up on a fresh machine (if needed) and run the test suite.
set -euo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/setup.sh"
exec python -m pytest -q "$@"
