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

# Debian packages. `apt-get update` runs at most once per script, and only when something is missing.
_apt_updated=""

missing_debian_packages() {  # prints those of "$@" that dpkg does not have installed
  local p
  for p in "$@"; do
    [ "$(dpkg-query -W -f='${Status}' "$p" 2>/dev/null)" = "install ok installed" ] || echo "$p"
  done
}

ensure_debian_packages() {  # installs the packages of "$@" that are missing; 1 when it could not
  if ! command -v dpkg-query >/dev/null 2>&1; then
    echo "note: not a Debian system (no dpkg-query): install the equivalents of these Debian packages yourself: $*" >&2
    return 0
  fi
  local missing
  missing=$(missing_debian_packages "$@")
  [ -z "$missing" ] && return 0
  missing=$(echo $missing)  # one line
  if ! command -v apt-get >/dev/null 2>&1; then
    echo "error: Debian packages missing: $missing; apt-get is not available to install them" >&2
    return 1
  fi
  local sudo=""
  if [ "$(id -u)" -ne 0 ]; then
    if ! command -v sudo >/dev/null 2>&1; then
      echo "error: Debian packages missing: $missing; run as root: apt-get install -y $missing" >&2
      return 1
    fi
    sudo="sudo"
  fi
  echo "installing Debian packages: $missing" >&2
  if [ -z "$_apt_updated" ]; then
    $sudo apt-get update -qq >/dev/null || { echo "error: apt-get update failed" >&2; return 1; }
    _apt_updated=1
  fi
  # shellcheck disable=SC2086  # one word per package
  DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -qq $missing >/dev/null \
    || { echo "error: apt-get install $missing failed" >&2; return 1; }
}

system_packages() {  # the package names of scripts/system-packages.txt, one a line
  sed 's/#.*//' "$(dirname "${BASH_SOURCE[0]}")/system-packages.txt" | awk 'NF { print $1 }'
}

# What the wheels link against and the base image lacks (scripts/system-packages.txt): needed by
# `import open3d` and so by every command; run before anything imports the wheels.
ensure_system_packages() {
  # shellcheck disable=SC2046
  ensure_debian_packages $(system_packages) || {
    echo "error: the system packages in scripts/system-packages.txt are needed (see README, 'System packages')" >&2
    return 1
  }
}

# Browser tests only (the demo does not need it).
ensure_chromium() {
  ensure_debian_packages chromium && [ -x /usr/bin/chromium ]
}
