#!/usr/bin/env bash
# The README's commands on a truly fresh Debian 12: build a throwaway minbase root with debootstrap,
# install in it only what the README's command 0 installs, copy the repository in (git archive of
# HEAD) and run commands 1 and 2 exactly as the README writes them. Needs root, debootstrap and the
# network (the Debian mirror and PyPI); of this machine only pip's CA bundle goes in (PyPI is reached
# through a TLS-inspecting proxy here), none of its Python, wheels or caches.
#
#   sudo .ci/fresh_debian.sh [ROOT]      # ROOT: an empty folder to build in (default: a temp dir)
#
# Environment: MIRROR (default: the mirror this machine's apt uses), KEEP=1 keeps the root afterwards,
# SKIP_TESTS=1 stops after command 1. Durations, sizes and each command's output tail are printed and
# kept under ROOT.log/ (next to the root). Exit status: that of the first command that failed.
set -euo pipefail
REPO=$(cd "$(dirname "$0")/.." && pwd)
ROOT=${1:-$(mktemp -d /tmp/fresh-debian.XXXXXX)}
ROOT=$(realpath -m "$ROOT")
LOG="$ROOT.log"
PORT=8080
mkdir -p "$ROOT" "$LOG"
[ "$(id -u)" = 0 ] || { echo "fresh_debian.sh: needs root (debootstrap, chroot, mount)" >&2; exit 2; }
[ -z "$(ls -A "$ROOT")" ] || { echo "fresh_debian.sh: $ROOT is not empty; give an empty or new folder" >&2; exit 2; }

# The mirror apt uses here (deb822 sources first, then the one-line format).
if [ -z "${MIRROR:-}" ]; then
    MIRROR=$(grep -h -o -E '^URIs: *[^ ]+/debian/?$' /etc/apt/sources.list.d/*.sources 2>/dev/null | head -1 | awk '{print $2}' || true)
    [ -n "$MIRROR" ] || MIRROR=$(grep -h -o -E '^deb +[^ ]+/debian/? ' /etc/apt/sources.list 2>/dev/null | head -1 | awk '{print $2}' || true)
    MIRROR=${MIRROR:-http://deb.debian.org/debian}
fi

# The README's numbered commands: the first non-comment line after "# N." in its first bash block.
readme_command() {
    python3 - "$REPO/README.md" "$1" <<'EOF'
import re, sys
block = re.search(r"```bash\n(.*?)```", open(sys.argv[1]).read(), re.S).group(1)
lines = [ln.strip() for ln in block.splitlines()]
start = next(i for i, ln in enumerate(lines) if ln.startswith(f"# {sys.argv[2]}."))
print(next(ln for ln in lines[start + 1:] if ln and not ln.startswith("#")))
EOF
}
# How pip reaches PyPI here: a CA bundle (PIP_CERT or pip.conf's cert, e.g. for a TLS-inspecting
# proxy) is copied in and named by PIP_CERT; index, timeout and proxy variables are passed on.
PIP_CA=${PIP_CERT:-$(python3 -c 'import configparser; c = configparser.ConfigParser(); c.read(["/etc/pip.conf", "/etc/xdg/pip/pip.conf"]); print(c.get("global", "cert", fallback=""))')}
CMD0=$(readme_command 0)
CMD1=$(readme_command 1)
CMD2=$(readme_command 2)

cleanup() {
    # Stop anything still running inside the root, then unmount before anything is deleted.
    for pid in $(ls /proc | grep -E '^[0-9]+$'); do
        [ "$(readlink /proc/$pid/root 2>/dev/null)" = "$ROOT" ] && kill -9 "$pid" 2>/dev/null || true
    done
    for m in dev/shm dev/pts dev sys proc; do
        mountpoint -q "$ROOT/$m" && umount -l "$ROOT/$m" || true
    done
    if [ "${KEEP:-0}" != 1 ]; then
        if findmnt -rn -o TARGET | grep -q "^$ROOT/"; then
            echo "fresh_debian.sh: something is still mounted under $ROOT; not deleting it" >&2
        else
            rm -rf --one-file-system "$ROOT"
        fi
    fi
}
trap cleanup EXIT

elapsed() { echo $(( $(date +%s) - $1 )); }
say() { echo "[fresh-debian $(date -u +%H:%M:%S)] $*" | tee -a "$LOG/summary.txt"; }
in_root() { chroot "$ROOT" /usr/bin/env -i HOME=/root TERM=dumb LANG=C.UTF-8 PATH=/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin \
    ${PIP_CA:+PIP_CERT=/etc/ssl/host-pip-ca.crt} ${PIP_INDEX_URL:+PIP_INDEX_URL=$PIP_INDEX_URL} ${PIP_DEFAULT_TIMEOUT:+PIP_DEFAULT_TIMEOUT=$PIP_DEFAULT_TIMEOUT} \
    ${http_proxy:+http_proxy=$http_proxy} ${https_proxy:+https_proxy=$https_proxy} ${no_proxy:+no_proxy=$no_proxy} \
    DEBIAN_FRONTEND=noninteractive bash -c "$1"; }
size_mb() { du -sxm "$1" | awk '{print $1}'; }

say "root $ROOT, mirror $MIRROR, pip CA bundle ${PIP_CA:-none}"
t=$(date +%s)
debootstrap --variant=minbase bookworm "$ROOT" "$MIRROR" >"$LOG/debootstrap.txt" 2>&1 \
    || { tail -20 "$LOG/debootstrap.txt"; exit 1; }
say "debootstrap minbase: $(elapsed $t) s, $(size_mb "$ROOT") MB"
cp /etc/resolv.conf "$ROOT/etc/resolv.conf"
if [ -n "$PIP_CA" ]; then mkdir -p "$ROOT/etc/ssl"; cp "$PIP_CA" "$ROOT/etc/ssl/host-pip-ca.crt"; fi
mount -t proc proc "$ROOT/proc"
mount -t sysfs sys "$ROOT/sys"
mount --bind /dev "$ROOT/dev"
mount --bind /dev/pts "$ROOT/dev/pts"
mount -t tmpfs -o size=2g shm "$ROOT/dev/shm"
in_root "apt-get update -qq && apt-get install -y python3" >"$LOG/python3.txt" 2>&1 \
    || { tail -20 "$LOG/python3.txt"; exit 1; }
BASE=$(size_mb "$ROOT")
say "python3 $(in_root 'python3 --version' | awk '{print $2}') installed, root $BASE MB"

# Command 0 as the README writes it (run as root here, so a leading sudo is dropped).
t=$(date +%s)
if ! in_root "${CMD0//sudo /}" >"$LOG/cmd0.txt" 2>&1; then tail -20 "$LOG/cmd0.txt"; say "command 0 FAILED"; exit 1; fi
say "command 0 ($CMD0): $(elapsed $t) s, +$(( $(size_mb "$ROOT") - BASE )) MB"

mkdir -p "$ROOT/root/l2e-studio"
git -C "$REPO" archive HEAD | tar -x -C "$ROOT/root/l2e-studio"
say "repository at $(git -C "$REPO" rev-parse --short HEAD) copied in (git archive HEAD)"
BASE=$(size_mb "$ROOT")

# Command 1: it installs, then the server answers on 127.0.0.1:8080; then it is stopped.
t=$(date +%s)
in_root "cd /root/l2e-studio && $CMD1" >"$LOG/cmd1.txt" 2>&1 &
CMD1_PID=$!
answered=0
for _ in $(seq 1 1800); do
    kill -0 "$CMD1_PID" 2>/dev/null || break
    if in_root "python3 -c 'import urllib.request as u; u.urlopen(\"http://127.0.0.1:$PORT\", timeout=2).read(1)'" 2>/dev/null; then
        answered=1; break
    fi
    sleep 1
done
say "command 1 ($CMD1): server on 127.0.0.1:$PORT answered=$answered after $(elapsed $t) s, .venv $(size_mb "$ROOT/root/l2e-studio/.venv") MB, root +$(( $(size_mb "$ROOT") - BASE )) MB"
for pid in $(ls /proc | grep -E '^[0-9]+$'); do
    [ "$(readlink /proc/$pid/root 2>/dev/null)" = "$ROOT" ] && kill "$pid" 2>/dev/null || true
done
wait "$CMD1_PID" 2>/dev/null || true
echo "--- command 1 output tail"; tail -15 "$LOG/cmd1.txt"
[ "$answered" = 1 ] || { say "command 1 FAILED: no answer on port $PORT"; exit 1; }
[ "${SKIP_TESTS:-0}" = 1 ] && exit 0

# Command 2: the test extras and the whole test suite, exactly as written.
t=$(date +%s)
status=0
in_root "cd /root/l2e-studio && $CMD2" >"$LOG/cmd2.txt" 2>&1 || status=$?
say "command 2 ($CMD2): exit $status after $(elapsed $t) s, .venv $(size_mb "$ROOT/root/l2e-studio/.venv") MB, root $(size_mb "$ROOT") MB"
echo "--- command 2 output tail"; tail -25 "$LOG/cmd2.txt"
exit "$status"
