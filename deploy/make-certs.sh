#!/usr/bin/env bash
# Make a throwaway certificate authority and one identity per host of a deployment: a certificate signed
# by that CA (common name = the identity) and a random Zenoh login (user = the identity). Needs openssl.
#
#   deploy/make-certs.sh DIR ADDRESSES NAME...
#   deploy/make-certs.sh secrets 10.0.0.1 cluster-a cluster-b
#
# ADDRESSES: the orchestrator's addresses as the other hosts reach it, comma-separated IPs or DNS names
# (127.0.0.1 and localhost are always added): TLS clients check the router's certificate against them.
# NAMEs: one identity per placement group (use the group names: access control reads them).
# Identities orchestrator, driver and monitor are always made. Writes DIR/<identity>/ with ca.pem,
# cert.pem, key.pem and credentials (user:password), plus DIR/orchestrator/users (every login, for the
# router). Copy DIR/<group>/ to the host of that group, and only that; DIR/ca/ (the CA's key) stays here.
set -euo pipefail

if [ $# -lt 2 ]; then
  echo "usage: $0 DIR ADDRESSES [NAME...]   e.g. $0 secrets 10.0.0.1 cluster-a cluster-b" >&2
  exit 2
fi
dir=$1
addresses=$2
shift 2
if [ -e "$dir" ]; then
  echo "$0: $dir exists; choose a new directory (keys are never overwritten)" >&2
  exit 2
fi

san="IP:127.0.0.1,DNS:localhost"
IFS=',' read -ra hosts <<< "$addresses"
for h in "${hosts[@]}"; do
  if [[ $h =~ ^[0-9.]+$ || $h == *:* ]]; then san="$san,IP:$h"; else san="$san,DNS:$h"; fi
done

umask 077
mkdir -p "$dir/ca"
openssl req -x509 -new -newkey ec -pkeyopt ec_paramgen_curve:prime256v1 -nodes -days 365 \
  -subj "/CN=zenohedge-ca" -keyout "$dir/ca/key.pem" -out "$dir/ca/ca.pem" \
  -addext "basicConstraints=critical,CA:TRUE" -addext "keyUsage=critical,keyCertSign,cRLSign" 2>/dev/null

: > "$dir/users"
for name in orchestrator driver monitor "$@"; do
  out=$dir/$name
  mkdir -p "$out"
  cp "$dir/ca/ca.pem" "$out/ca.pem"
  openssl req -new -newkey ec -pkeyopt ec_paramgen_curve:prime256v1 -nodes -subj "/CN=$name" \
    -keyout "$out/key.pem" -out "$out/req.csr" 2>/dev/null
  printf 'basicConstraints=critical,CA:FALSE\nkeyUsage=critical,digitalSignature\n%s\n%s\n' \
    "extendedKeyUsage=serverAuth,clientAuth" "subjectAltName=$san" > "$out/ext.cnf"
  openssl x509 -req -in "$out/req.csr" -CA "$dir/ca/ca.pem" -CAkey "$dir/ca/key.pem" -CAcreateserial \
    -days 365 -extfile "$out/ext.cnf" -out "$out/cert.pem" 2>/dev/null
  rm "$out/req.csr" "$out/ext.cnf"
  echo "$name:$(openssl rand -hex 16)" > "$out/credentials"
  cat "$out/credentials" >> "$dir/users"
done
mv "$dir/users" "$dir/orchestrator/users"
echo "$dir: CA in $dir/ca/; identities: orchestrator driver monitor $*"
