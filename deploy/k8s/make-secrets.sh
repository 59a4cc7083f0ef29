#!/usr/bin/env bash
# The Secrets the manifests mount, made by coadapt itself (`coadapt tls new`, `coadapt token
# new`): coadapt-tls (ca.pem, server.pem, server-key.pem for the learner's Service names),
# coadapt-tokens (the learner's accepted tokens: SHA-256 hashes, no secret), coadapt-actor-token
# and coadapt-optimizer-token (one token each), a client token for design clients and the
# operator page's viewers, and an operator token for the page's prototype answers, written to
# OUT/client.token and OUT/operator.token only (give them to your tools and the workshop; their
# hashes are in coadapt-tokens).
#
# Usage: deploy/k8s/make-secrets.sh [--namespace NS] [--out DIR] [--bin COADAPT] [--apply]
#   --out DIR     where the files go (default ./coadapt-secrets; created, must not exist)
#   --apply       kubectl apply the Secrets (else their YAML is written to OUT/secrets.yaml)
# The CA key (OUT/tls/ca-key.pem) never goes to the cluster: keep it offline.
set -euo pipefail

die() { printf 'make-secrets.sh: error: %s\n' "$*" >&2; exit 2; }
namespace=default
out=coadapt-secrets
bin=${COADAPT_BIN:-coadapt}
apply=0
while [[ $# -gt 0 ]]; do
  case $1 in
    -h | --help) sed -n '2,13p' "${BASH_SOURCE[0]}" | sed 's/^# \{0,1\}//'; exit 0 ;;
    --namespace) [[ $# -ge 2 ]] || die "--namespace needs a value"; namespace=$2; shift 2 ;;
    --out) [[ $# -ge 2 ]] || die "--out needs a value"; out=$2; shift 2 ;;
    --bin) [[ $# -ge 2 ]] || die "--bin needs a value"; bin=$2; shift 2 ;;
    --apply) apply=1; shift ;;
    *) die "unknown argument '$1' (see --help)" ;;
  esac
done
command -v "$bin" >/dev/null 2>&1 || die "no coadapt binary '$bin' (--bin PATH, or cargo build --release -p coadapt)"
command -v kubectl >/dev/null 2>&1 || die "kubectl not found: it writes the Secrets' YAML"
[[ ! -e $out ]] || die "$out exists: secrets are never overwritten (choose another --out)"
umask 077
mkdir -p -- "$out"
"$bin" tls new --out "$out/tls" --host coadapt-learner --host "coadapt-learner.$namespace" \
  --host "coadapt-learner.$namespace.svc" --host "coadapt-learner.$namespace.svc.cluster.local"
for role in actor optimizer client operator; do
  "$bin" token new --role "$role" --out "$out/$role.token" --tokens-file "$out/tokens"
done
secret() { kubectl create secret generic "$@" --namespace "$namespace" --dry-run=client -o yaml; }
{
  secret coadapt-tls --from-file=ca.pem="$out/tls/ca.pem" --from-file=server.pem="$out/tls/server.pem" \
    --from-file=server-key.pem="$out/tls/server-key.pem"
  echo ---
  secret coadapt-tokens --from-file=tokens="$out/tokens"
  echo ---
  secret coadapt-actor-token --from-file=token="$out/actor.token"
  echo ---
  secret coadapt-optimizer-token --from-file=token="$out/optimizer.token"
} >"$out/secrets.yaml"
if ((apply)); then
  kubectl apply -f "$out/secrets.yaml"
  printf 'make-secrets.sh: Secrets applied in namespace %s; client token: %s, operator token: %s\n' "$namespace" "$out/client.token" "$out/operator.token" >&2
else
  printf 'make-secrets.sh: wrote %s (kubectl apply -f it); client token: %s, operator token: %s\n' "$out/secrets.yaml" "$out/client.token" "$out/operator.token" >&2
fi
