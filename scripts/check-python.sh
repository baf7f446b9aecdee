#!/bin/sh
# Fail early, with the fix, when the interpreter is too old or cannot make a virtual environment.
set -eu
py="$1"
command -v "$py" >/dev/null 2>&1 || { echo "armvision: '$py' not found; install Python >= 3.10 (apt-get install python3 python3-venv)" >&2; exit 1; }
"$py" -c 'import sys; sys.exit(sys.version_info < (3, 10))' || {
    echo "armvision: $("$py" --version 2>&1) is too old; armvision needs Python >= 3.10 (make PYTHON=python3.11 ...)" >&2; exit 1; }
if ! "$py" -c 'import ensurepip, venv' >/dev/null 2>&1; then
    # Debian splits venv/ensurepip out of python3 itself.
    ver=$("$py" -c 'import sys; print(f"{sys.version_info[0]}.{sys.version_info[1]}")')
    sh "$(dirname "$0")/system-packages.sh" "python$ver-venv"
fi
