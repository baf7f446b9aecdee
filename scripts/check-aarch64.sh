#!/bin/sh
# `make check-aarch64`: install and run armvision on arm64 Debian under emulation.
#
# An arm64 Debian bookworm (Python 3.11) made by mmdebstrap from Debian's packages, run through
# qemu-user-static (binfmt_misc); `make setup` installs armvision there from a copy of this
# tree, then `armvision info`, `armvision perceive` on a saved frame and a fast subset of the
# tests run inside it. The base system is kept in build/aarch64-bookworm.tar (made once, ~4 min);
# the root filesystem build/aarch64-root is unpacked fresh from it on every run, so `make setup`
# starts from a bare system each time (AARCH64_REUSE=1 keeps the last one: setup is then
# instant, for rerunning the checks). Needs root (chroot, mounts) and the network (Debian's
# mirror, PyPI). Usage: sh scripts/check-aarch64.sh FRAME_DIR (a `sim snapshot` folder).
set -eu
frame_dir="$1"
here=$(pwd)
base="build/aarch64-bookworm.tar"
root="build/aarch64-root"
mirror="${AARCH64_MIRROR:-http://deb.debian.org/debian}"
tests="tests/robot/test_kinematics.py tests/calibration/test_solve.py tests/test_config.py
tests/test_geometry.py tests/perception/test_perceive_files.py tests/perception/test_fitting.py"

[ "$(id -u)" -eq 0 ] || { echo "check-aarch64: needs root (chroot and mounts)" >&2; exit 1; }
start=$(date +%s)
step() { echo "check-aarch64 [$(($(date +%s) - start)) s]: $*"; }

sh scripts/system-packages.sh mmdebstrap qemu-user-static binfmt-support arch-test
# Foreign binaries run through binfmt_misc; in a container it may need mounting first.
if [ ! -e /proc/sys/fs/binfmt_misc/status ]; then
    mount -t binfmt_misc binfmt_misc /proc/sys/fs/binfmt_misc || {
        echo "check-aarch64: cannot mount binfmt_misc (a container without the privilege?);" \
            "mmdebstrap needs it to run arm64 package scripts" >&2
        exit 1
    }
fi
[ -e /proc/sys/fs/binfmt_misc/qemu-aarch64 ] || update-binfmts --enable qemu-aarch64
arch-test arm64 >/dev/null || {
    echo "check-aarch64: arm64 binaries do not run here (arch-test arm64 fails):" \
        "is qemu-aarch64 registered in /proc/sys/fs/binfmt_misc?" >&2
    exit 1
}

if [ ! -s "$base" ]; then
    step "making the arm64 bookworm base system ($base) from $mirror"
    mkdir -p build
    mmdebstrap --quiet --format=tar --arch=arm64 --variant=minbase --include=python3,make,ca-certificates \
        bookworm "$base.tmp" "$mirror"  # .tmp: the format is given, not guessed
    mv "$base.tmp" "$base"
fi

cleanup() {
    for m in dev/pts dev sys proc; do
        mountpoint -q "$here/$root/$m" && umount -l "$here/$root/$m"
    done
    return 0
}
trap cleanup EXIT
cleanup
# Never delete through a bind mount of the host's /dev or /sys.
if grep -q " $here/$root/" /proc/mounts; then
    echo "check-aarch64: something is still mounted under $root; unmount it first" >&2
    exit 1
fi
if [ "${AARCH64_REUSE:-0}" = 1 ] && [ -x "$root/usr/bin/python3" ]; then
    step "reusing the root filesystem of the last run ($root, AARCH64_REUSE=1)"
else
    rm -rf "$root"
    mkdir -p "$root"
    step "unpacking the root filesystem ($root)"
    tar -xf "$base" -C "$root"
fi
cp /etc/resolv.conf "$root/etc/resolv.conf"
# pip inside trusts the host's CA bundle: a machine that reaches PyPI through a TLS proxy has
# the proxy's CA there only (elsewhere it is the same public CAs as Debian's own bundle).
cp "${PIP_CERT:-/etc/ssl/certs/ca-certificates.crt}" "$root/etc/ssl/host-ca-certificates.crt"
mount -t proc proc "$root/proc"
mount --rbind /sys "$root/sys"
mount --bind /dev "$root/dev"
mount --bind /dev/pts "$root/dev/pts"

# The tree as git sees it (tracked and new files, nothing ignored: no .venv, build or out).
mkdir -p "$root/root/armvision/frame"
git ls-files -z --cached --others --exclude-standard | xargs -0 tar -cf - | tar -xf - -C "$root/root/armvision"
cp "$frame_dir/color.png" "$frame_dir/depth_mm.png" "$frame_dir/ground_truth.json" \
    "$root/root/armvision/frame/"

# Mesa's llvmpipe crashes under qemu-user (its JIT: MuJoCo's EGL rendering ends in SIGSEGV);
# softpipe, Mesa's renderer without a JIT, renders there.
in_root() {
    chroot "$root" /usr/bin/env -i HOME=/root PATH=/usr/sbin:/usr/bin:/sbin:/bin LANG=C.UTF-8 \
        MUJOCO_GL=egl GALLIUM_DRIVER=softpipe PIP_CERT=/etc/ssl/host-ca-certificates.crt \
        SSL_CERT_FILE=/etc/ssl/host-ca-certificates.crt /bin/sh -c "cd /root/armvision && $1"
}
step "inside: $(in_root 'uname -m; python3 --version' | tr '\n' ' ')"
step "make setup"
t0=$(date +%s)
in_root "make setup"
setup_s=$(($(date +%s) - t0))
step "armvision info"
in_root ".venv/bin/armvision info"
step "armvision perceive on a saved frame"
t0=$(date +%s)
in_root ".venv/bin/armvision perceive --color frame/color.png --depth frame/depth_mm.png \
    --intrinsics frame/ground_truth.json --out /tmp/perceive"
perceive_s=$(($(date +%s) - t0))
step "tests: $(echo $tests)"
t0=$(date +%s)
in_root ".venv/bin/python -m pytest -q -p no:cacheprovider $(echo $tests)"
tests_s=$(($(date +%s) - t0))
total=$(($(date +%s) - start))
echo "check-aarch64: OK in $total s (make setup $setup_s s, perceive $perceive_s s, tests $tests_s s)"
