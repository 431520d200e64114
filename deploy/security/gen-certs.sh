#!/usr/bin/env bash
# Generate the certificates of a formation fleet for Zenoh mutual TLS (mTLS).
#
# One private certificate authority (CA) signs:
#   router/       the Zenoh router on the coordinator host (server + client usage,
#                 subjectAltName = every --router-host given, so robots can keep
#                 verify_name_on_connect = true)
#   coordinator/  the coordinator process (client certificate, CN = coordinator name)
#   robots/<id>/  one per robot (client certificate, CN = robot id)
#
# The CN of each client certificate is its identity: the router's access_control
# (deploy/zenoh/router-mtls.json5) matches it with `cert_common_names`.
# Every identity directory holds cert.pem, key.pem (PKCS#8, mode 0600) and a copy of
# ca.pem, so it can be copied as-is to /etc/formation/certs/ on its host.
# The CA key (ca/ca.key) never leaves the machine that runs this script.
#
# Keys are ECDSA P-256 (rustls accepts them; generating them takes milliseconds on a Pi).
# Re-running the script keeps the existing CA and any existing identity unless --force
# is given, so adding a robot later is `gen-certs.sh -o DIR r4`.
#
# usage: gen-certs.sh [-o OUTDIR] [--router-host NAME_OR_IP]... [--coordinator NAME]
#                     [--days N] [--force] [ROBOT_ID...]
set -euo pipefail

out_dir="./formation-certs"
router_hosts=()
coordinator="coordinator"
days=825
force=0
robots=()

usage() {
    sed -n '2,/^set -euo/p' "$0" | sed -e '$d' -e 's/^# \{0,1\}//'
}

while [[ $# -gt 0 ]]; do
    case "$1" in
        -o|--out) out_dir="$2"; shift 2 ;;
        --router-host) router_hosts+=("$2"); shift 2 ;;
        --coordinator) coordinator="$2"; shift 2 ;;
        --days) days="$2"; shift 2 ;;
        --force) force=1; shift ;;
        -h|--help) usage; exit 0 ;;
        --) shift; robots+=("$@"); break ;;
        -*) echo "gen-certs.sh: unknown option $1" >&2; exit 2 ;;
        *) robots+=("$1"); shift ;;
    esac
done

id_re='^[a-z0-9_-]+$'
for name in "$coordinator" "${robots[@]}"; do
    if [[ ! "$name" =~ $id_re ]]; then
        echo "gen-certs.sh: identity '$name' must match [a-z0-9_-]+" >&2
        exit 2
    fi
done
if [[ ! "$days" =~ ^[0-9]+$ ]] || [[ "$days" -lt 1 ]]; then
    echo "gen-certs.sh: --days must be a positive integer" >&2
    exit 2
fi
if [[ ${#router_hosts[@]} -eq 0 ]]; then
    router_hosts=("localhost" "127.0.0.1")
fi
command -v openssl >/dev/null || { echo "gen-certs.sh: openssl not found" >&2; exit 1; }

umask 077
mkdir -p "$out_dir/ca"
ca_key="$out_dir/ca/ca.key"
ca_pem="$out_dir/ca/ca.pem"

new_key() {  # $1 = path
    openssl genpkey -algorithm EC -pkeyopt ec_paramgen_curve:P-256 -out "$1" 2>/dev/null
    chmod 600 "$1"
}

if [[ $force -eq 1 || ! -s "$ca_key" || ! -s "$ca_pem" ]]; then
    new_key "$ca_key"
    openssl req -x509 -new -key "$ca_key" -sha256 -days "$days" \
        -subj "/O=formation/CN=formation fleet CA" \
        -addext "basicConstraints=critical,CA:TRUE,pathlen:0" \
        -addext "keyUsage=critical,keyCertSign,cRLSign" \
        -addext "subjectKeyIdentifier=hash" \
        -out "$ca_pem"
    chmod 644 "$ca_pem"
    echo "created CA $ca_pem"
fi

# issue DIR CN EKU [SAN]: a key and a CA-signed certificate with the given identity.
issue() {
    local dir="$1" cn="$2" eku="$3" san="${4:-}"
    if [[ $force -eq 0 && -s "$dir/cert.pem" && -s "$dir/key.pem" ]]; then
        echo "kept    $dir (exists; --force to replace)"
        return
    fi
    mkdir -p "$dir"
    new_key "$dir/key.pem"
    local ext="$dir/.ext.cnf"
    {
        echo "basicConstraints=critical,CA:FALSE"
        echo "keyUsage=critical,digitalSignature"
        echo "extendedKeyUsage=$eku"
        echo "subjectKeyIdentifier=hash"
        echo "authorityKeyIdentifier=keyid"
        if [[ -n "$san" ]]; then echo "subjectAltName=$san"; fi
    } >"$ext"
    openssl req -new -key "$dir/key.pem" -subj "/O=formation/CN=$cn" -out "$dir/cert.csr"
    openssl x509 -req -in "$dir/cert.csr" -CA "$ca_pem" -CAkey "$ca_key" \
        -CAcreateserial -days "$days" -sha256 -extfile "$ext" -out "$dir/cert.pem" 2>/dev/null
    rm -f "$dir/cert.csr" "$ext"
    cp "$ca_pem" "$dir/ca.pem"
    chmod 644 "$dir/cert.pem" "$dir/ca.pem"
    echo "created $dir (CN=$cn)"
}

san=""
for host in "${router_hosts[@]}"; do
    if [[ "$host" =~ ^[0-9.]+$ || "$host" == *:* ]]; then
        san+="${san:+,}IP:$host"
    else
        san+="${san:+,}DNS:$host"
    fi
done

issue "$out_dir/router" "router" "serverAuth,clientAuth" "$san"
issue "$out_dir/coordinator" "$coordinator" "clientAuth" "DNS:$coordinator"
for id in "${robots[@]}"; do
    issue "$out_dir/robots/$id" "$id" "clientAuth" "DNS:$id"
done
# ca/ca.srl keeps the serial counter of the CA: keep it with ca.key.
