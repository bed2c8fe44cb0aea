#!/usr/bin/env bash
# Build a base image for deploy/Dockerfile from Debian packages, for machines that cannot pull from Docker Hub.
#
#   deploy/make-base-image.sh [TAG]          # default TAG: capataz-base:bookworm
#   docker build --network=host --build-arg BASE_IMAGE=capataz-base:bookworm -f deploy/Dockerfile -t capataz:0.1.0 .
#
# debootstrap (a Debian package: apt-get install debootstrap) unpacks a minimal Debian bookworm with python3,
# venv, tini and util-linux into a temporary folder; `docker import` turns that folder into an image. Needs
# root (debootstrap chroots) and a reachable Debian mirror (MIRROR, default deb.debian.org). The host's extra
# certificate authorities (/usr/local/share/ca-certificates) are copied in, so pip works behind a TLS proxy.
set -euo pipefail

TAG="${1:-capataz-base:bookworm}"
SUITE="${SUITE:-bookworm}"
MIRROR="${MIRROR:-http://deb.debian.org/debian}"
PACKAGES="python3,python3-venv,python3-pip,tini,util-linux,ca-certificates,openssl"

for tool in debootstrap docker; do
    command -v "$tool" >/dev/null || { echo "make-base-image: $tool not found (apt-get install $tool)" >&2; exit 1; }
done
[ "$(id -u)" -eq 0 ] || { echo "make-base-image: debootstrap needs root" >&2; exit 1; }
docker info >/dev/null 2>&1 || { echo "make-base-image: no Docker engine answers (docker info failed)" >&2; exit 1; }

ROOTFS="$(mktemp -d /tmp/capataz-rootfs.XXXXXX)"
trap 'rm -rf "$ROOTFS"' EXIT

start=$(date +%s)
echo "make-base-image: debootstrap $SUITE ($PACKAGES) into $ROOTFS"
debootstrap --variant=minbase --include="$PACKAGES" "$SUITE" "$ROOTFS" "$MIRROR" >"$ROOTFS.log" 2>&1 \
    || { echo "make-base-image: debootstrap failed, see $ROOTFS.log" >&2; exit 1; }
# slim it like the official slim images: no apt lists, docs, man pages or locales beyond C
rm -rf "$ROOTFS"/var/lib/apt/lists/* "$ROOTFS"/var/cache/apt/*.bin "$ROOTFS"/var/cache/apt/archives/*.deb \
    "$ROOTFS"/usr/share/doc/* "$ROOTFS"/usr/share/man/* "$ROOTFS"/usr/share/info/*
# the host's own certificate authorities (a site proxy that inspects TLS, as on this project's machines): the
# image's pip reaches PyPI through the same proxy. HOST_CA=0 leaves them out.
if [ "${HOST_CA:-1}" != 0 ] && compgen -G "/usr/local/share/ca-certificates/*.crt" >/dev/null; then
    cp /usr/local/share/ca-certificates/*.crt "$ROOTFS/usr/local/share/ca-certificates/"
    chroot "$ROOTFS" update-ca-certificates >/dev/null 2>&1
fi
# apt inside the image keeps working (the Dockerfile may install more packages)
echo "deb $MIRROR $SUITE main" >"$ROOTFS/etc/apt/sources.list"

chmod 755 "$ROOTFS"  # mktemp made it 0700: the image's / would be closed to the non-root user
tar -C "$ROOTFS" -c . | docker import \
    --change 'ENV PATH=/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin' \
    --change 'ENV LANG=C.UTF-8' \
    --change 'CMD ["/bin/bash"]' \
    - "$TAG" >/dev/null
rm -f "$ROOTFS.log"
echo "make-base-image: $TAG in $(( $(date +%s) - start )) s, $(docker image inspect -f '{{.Size}}' "$TAG" | awk '{printf "%.0f MB", $1/1e6}')"
