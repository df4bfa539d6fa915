#!/bin/sh
# TEST-ONLY certificates for the TLS example configs: a throw-away CA and one server
# certificate for localhost / 127.0.0.1 / ::1, valid 30 days. Private keys are written
# unencrypted. Never use these on a real bus: make your own CA (or use your lab's PKI).
#   sh scenarios/zenoh/make-test-certs.sh [OUTDIR]   (default: the tls/ folder next to this)
set -eu
out="${1:-$(dirname "$0")/tls}"
mkdir -p "$out"
cd "$out"
openssl req -x509 -newkey ec -pkeyopt ec_paramgen_curve:prime256v1 -nodes -days 30 \
    -subj "/CN=beamrelay test CA" -keyout ca-key.pem -out ca.pem 2>/dev/null
openssl req -newkey ec -pkeyopt ec_paramgen_curve:prime256v1 -nodes \
    -subj "/CN=localhost" -keyout server-key.pem -out server.csr 2>/dev/null
printf 'subjectAltName=DNS:localhost,IP:127.0.0.1,IP:::1\nbasicConstraints=CA:FALSE\n' \
    > server.ext
openssl x509 -req -in server.csr -CA ca.pem -CAkey ca-key.pem -CAcreateserial -days 30 \
    -extfile server.ext -out server.pem 2>/dev/null
rm -f server.csr server.ext ca.srl
echo "test certificates in $out: ca.pem, server.pem, server-key.pem (TEST ONLY)"
