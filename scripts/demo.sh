#!/usr/bin/env bash
# Install the Debian packages the wheels need (scripts/system-packages.txt), create .venv,
# install clutt3r (CPU torch), generate a pre/post scene, segment, update, query and grasp it and
# serve the viewer with a guided tour on http://127.0.0.1:8080 (Ctrl-C stops it; docs/demo.md).
# Extra args go to `clutt3r demo` (e.g. --scene PATH for a real sample).
set -euo pipefail
cd "$(dirname "$0")/.."
source scripts/_env.sh
ensure_system_packages
ensure_venv '.[language]'   # the offline language backend: text queries in the demo
exec .venv/bin/clutt3r demo "$@"
