#!/usr/bin/env bash
# Install the Docker Compose v2 CLI plugin (`docker compose`) from Debian's own package, for machines whose
# Debian release ships only Compose v1 (bookworm: docker-compose 1.29) and that cannot reach Docker's servers.
#
#   deploy/install-compose-v2.sh                 # into /usr/libexec/docker/cli-plugins (root)
#   PLUGIN_DIR=~/.docker/cli-plugins deploy/install-compose-v2.sh      # per user, no root
#
# Debian trixie's `docker-compose` package is Compose v2 (a static Go binary that needs only libc >= 2.34,
# which bookworm has). The script reads the trixie package index from the mirror (MIRROR, default
# deb.debian.org), downloads that one .deb, and copies its plugin binary out; nothing else on the host
# changes (bookworm's Compose v1 `docker-compose` stays as it is).
set -euo pipefail

MIRROR="${MIRROR:-http://deb.debian.org/debian}"
SUITE="${SUITE:-trixie}"
ARCH="${ARCH:-$(dpkg --print-architecture 2>/dev/null || echo amd64)}"
PLUGIN_DIR="${PLUGIN_DIR:-/usr/libexec/docker/cli-plugins}"

for tool in curl xz dpkg-deb; do
    command -v "$tool" >/dev/null || { echo "install-compose-v2: $tool not found" >&2; exit 1; }
done
WORK="$(mktemp -d /tmp/capataz-compose.XXXXXX)"
trap 'rm -rf "$WORK"' EXIT

curl -fsS "$MIRROR/dists/$SUITE/main/binary-$ARCH/Packages.xz" -o "$WORK/Packages.xz" \
    || { echo "install-compose-v2: cannot read the $SUITE package index from $MIRROR" >&2; exit 1; }
xz -d "$WORK/Packages.xz"
FILE="$(awk '/^Package: docker-compose$/{p=1} p&&/^Filename:/{print $2; exit}' "$WORK/Packages")"
[ -n "$FILE" ] || { echo "install-compose-v2: no docker-compose package in $SUITE/$ARCH" >&2; exit 1; }
curl -fsS "$MIRROR/$FILE" -o "$WORK/compose.deb" \
    || { echo "install-compose-v2: download of $FILE failed" >&2; exit 1; }
dpkg-deb -x "$WORK/compose.deb" "$WORK/root"
BINARY="$WORK/root/usr/libexec/docker/cli-plugins/docker-compose"
[ -x "$BINARY" ] || { echo "install-compose-v2: $FILE holds no cli-plugins/docker-compose" >&2; exit 1; }
mkdir -p "$PLUGIN_DIR"
install -m 0755 "$BINARY" "$PLUGIN_DIR/docker-compose"
echo "install-compose-v2: $("$PLUGIN_DIR/docker-compose" version) -> $PLUGIN_DIR/docker-compose"
