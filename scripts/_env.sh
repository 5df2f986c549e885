# Shared by scripts/demo.sh and scripts/test.sh: a project-local virtual environment.
PY=${PYTHON:-python3.11}
command -v "$PY" >/dev/null 2>&1 || PY=python3

pip_args=(-q --disable-pip-version-check)
# The machine keeps a CPU build of torch in /opt/wheels; without it pip would fetch it from PyPI.
[ -d /opt/wheels ] && pip_args+=(--find-links /opt/wheels)

ensure_venv() {
  local spec=$1
  [ -x .venv/bin/python ] || "$PY" -m venv .venv
  .venv/bin/python -m pip install "${pip_args[@]}" --upgrade pip >/dev/null
  .venv/bin/python -m pip install "${pip_args[@]}" -e "$spec"
}

ensure_chromium() {
  [ -x /usr/bin/chromium ] && return 0
  command -v apt-get >/dev/null 2>&1 || return 1
  local sudo=""
  [ "$(id -u)" -ne 0 ] && sudo="sudo"
  $sudo apt-get update -qq >/dev/null && DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -qq chromium >/dev/null
}
