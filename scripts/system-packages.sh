#!/bin/sh
# Install the Debian packages armvision needs, only those missing; silent and fast when all are there.
set -eu
command -v dpkg-query >/dev/null 2>&1 || {
    echo "armvision: not a Debian/Ubuntu system; make sure these are installed: $*" >&2
    exit 0
}
missing=""
for pkg in "$@"; do
    status=$(dpkg-query -W -f='${db:Status-Status}' "$pkg" 2>/dev/null || true)
    [ "$status" = "installed" ] || missing="$missing $pkg"
done
[ -n "$missing" ] || exit 0
echo "armvision: installing Debian packages:$missing"
if [ "$(id -u)" -eq 0 ]; then
    SUDO=""
elif command -v sudo >/dev/null 2>&1; then
    SUDO="sudo"
else
    echo "armvision: run as root: apt-get install -y$missing" >&2
    exit 1
fi
$SUDO apt-get update -qq
DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq --no-install-recommends $missing
