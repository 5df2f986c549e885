#!/usr/bin/env bash
# Install the Debian packages the wheels need (scripts/system-packages.txt), create .venv,
# install clutt3r with its test extras (CPU torch), make sure Debian's
# chromium is there for the browser tests, run the whole test suite.
set -euo pipefail
cd "$(dirname "$0")/.."
source scripts/_env.sh
ensure_system_packages
ensure_venv '.[test,language]'   # language too: its tests run the real models
ensure_chromium || echo "warning: chromium could not be installed; browser tests will be skipped" >&2
exec .venv/bin/python -m pytest -n 2 --dist loadfile -q "$@"
