#!/usr/bin/env bash
# Development CA and one certificate per capataz role (CN = role, or role.uav for UAV-bound roles).
#
#   deploy/secure/make-certs.sh [OUT_DIR] [UAV ...]        default: out/secure/certs uav0 uav1
#   NODES="h1 h2" deploy/secure/make-certs.sh ...           nodes of the foremen and workers (default h1 h2 h3)
#
# CNs: router, client; foreman.NODE and worker.NODE per node; camera/master/estimator/localizer.UAV per UAV.
#
# The CA's private key lives apart from the role keys, in CA_DIR (default: OUT_DIR-ca, beside it), so that the
# folder mounted or copied to participants never holds it; OUT_DIR holds ca.pem and the role certificates
# and keys. Both folders are 0700, keys 0600, certificates 0644, whatever the umask.
# Re-running it ROTATES the role certificates (new keys, signed by the existing CA); remove CA_DIR/ca.key
# and OUT_DIR/ca.pem first (or set NEW_CA=1) to rotate the CA too, which every participant must then get.
# DAYS (default 30) sets the validity. Production: use your own CA and keep ca.key off the machines; only
# ca.pem and each participant's own cert/key are deployed.
set -euo pipefail
out="${1:-out/secure/certs}"
shift || true
uavs=("$@")
[ ${#uavs[@]} -gt 0 ] || uavs=(uav0 uav1)
days="${DAYS:-30}"
command -v openssl >/dev/null || { echo "make-certs: openssl not found" >&2; exit 2; }
read -r -a nodes <<< "${NODES:-h1 h2 h3}"
for uav in "${uavs[@]}"; do
  [[ "$uav" =~ ^[A-Za-z0-9_-]+$ ]] || { echo "make-certs: bad UAV name '$uav'" >&2; exit 2; }
done
for node in "${nodes[@]}"; do
  [[ "$node" =~ ^[A-Za-z0-9_-]+$ ]] || { echo "make-certs: bad node name '$node'" >&2; exit 2; }
done
umask 077
ca_dir="${CA_DIR:-${out%/}-ca}"
mkdir -p "$out" "$ca_dir"
chmod 700 "$out" "$ca_dir"
# a CA key left among the role keys by an older version moves to its own folder
if [ -s "$out/ca.key" ] && [ ! -s "$ca_dir/ca.key" ]; then mv "$out/ca.key" "$ca_dir/ca.key"; fi
rm -f "$out/ca.key" "$out/ca.srl"
if [ "${NEW_CA:-0}" = 1 ] || [ ! -s "$ca_dir/ca.key" ] || [ ! -s "$out/ca.pem" ]; then
  openssl req -x509 -newkey ec -pkeyopt ec_paramgen_curve:P-256 -nodes -sha256 -days "$((days * 4))" \
    -keyout "$ca_dir/ca.key" -out "$out/ca.pem" -subj "/CN=capataz development CA" \
    -addext "basicConstraints=critical,CA:TRUE" -addext "keyUsage=critical,keyCertSign,cRLSign" 2>/dev/null
  echo "make-certs: new CA $out/ca.pem"
fi
names=(router client)
for node in "${nodes[@]}"; do names+=("foreman.$node" "worker.$node"); done
for uav in "${uavs[@]}"; do names+=("camera.$uav" "master.$uav" "estimator.$uav" "localizer.$uav"); done
ext="$(mktemp)"
trap 'rm -f "$ext" "$out"/*.csr' EXIT
for cn in "${names[@]}"; do
  host="${cn%%.*}"
  printf '%s\n' "basicConstraints=CA:FALSE" "keyUsage=critical,digitalSignature,keyEncipherment" \
    "extendedKeyUsage=serverAuth,clientAuth" "subjectAltName=DNS:localhost,IP:127.0.0.1,DNS:$host" > "$ext"
  openssl req -newkey ec -pkeyopt ec_paramgen_curve:P-256 -nodes -sha256 \
    -keyout "$out/$cn.key" -out "$out/$cn.csr" -subj "/CN=$cn" 2>/dev/null
  openssl x509 -req -sha256 -days "$days" -in "$out/$cn.csr" -CA "$out/ca.pem" -CAkey "$ca_dir/ca.key" \
    -CAserial "$ca_dir/ca.srl" -CAcreateserial -out "$out/$cn.pem" -extfile "$ext" 2>/dev/null
  openssl verify -CAfile "$out/ca.pem" "$out/$cn.pem" >/dev/null
done
chmod 600 "$out"/*.key "$ca_dir"/ca.key
chmod 644 "$out"/*.pem
echo "make-certs: ${#names[@]} role certificates in $out (valid $days days): ${names[*]}"
