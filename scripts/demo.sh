#!/usr/bin/env bash
# Install the Debian packages the wheels need (scripts/system-packages.txt), create .venv,
# install clutt3r (CPU torch), generate a cluttered scene, segment it and
# serve the viewer on http://127.0.0.1:8080 (Ctrl-C stops it). Extra args go to `clutt3r demo`.
set -euo pipefail
cd "$(dirname "$0")/.."
source scripts/_env.sh
ensure_system_packages
ensure_venv '.[language]'   # the offline language backend: text queries in the demo
exec .venv/bin/clutt3r demo "$@"
