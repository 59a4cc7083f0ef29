#!/usr/bin/env bash
# Offline checks of the Kubernetes manifests (no cluster needed):
#   1. every YAML file here parses (PyYAML safe_load_all);
#   2. every kustomization builds (kubectl kustomize, or kustomize);
#   3. every built object validates against the Kubernetes OpenAPI schemas, strictly (unknown
#      fields are errors), with kubernetes-validate from PyPI, for the oldest Kubernetes the
#      manifests need (1.28: the pod-index label) and the newest it knows.
# PyYAML and kubernetes-validate go into deploy/.venv (created on first use; ignored by git).
# Exit: 0 clean; 1 a finding; 77 a tool is missing and cannot be installed (printed).
set -euo pipefail

case ${1:-} in
  -h | --help)
    sed -n '2,9p' "${BASH_SOURCE[0]}" | sed 's/^# \{0,1\}//'
    exit 0
    ;;
esac
K8S_DIR=$(cd -- "$(dirname -- "${BASH_SOURCE[0]}")" && pwd)
VENV=$K8S_DIR/../.venv
say() { printf 'validate.sh: %s\n' "$*" >&2; }

if [[ ! -x $VENV/bin/kubernetes-validate ]]; then
  command -v python3 >/dev/null 2>&1 || { say "SKIP: python3 not found"; exit 77; }
  say "installing PyYAML and kubernetes-validate into $VENV"
  if ! { python3 -m venv "$VENV" && "$VENV/bin/pip" install -q pyyaml kubernetes-validate; }; then
    say "SKIP: could not install pyyaml and kubernetes-validate from PyPI"
    exit 77
  fi
fi
if command -v kubectl >/dev/null 2>&1; then
  build() { kubectl kustomize "$1"; }
elif command -v kustomize >/dev/null 2>&1; then
  build() { kustomize build "$1"; }
else
  say "SKIP: neither kubectl nor kustomize found (the kustomizations cannot be built)"
  exit 77
fi

failed=0
# 1. Every YAML file parses.
mapfile -t files < <(find "$K8S_DIR" -name '*.yaml' | sort)
"$VENV/bin/python" - "${files[@]}" <<'PY' || failed=1
import sys, yaml
bad = 0
for path in sys.argv[1:]:
    try:
        docs = [d for d in yaml.safe_load_all(open(path)) if d is not None]
        kinds = ", ".join(d.get("kind", "?") for d in docs)
        print(f"  parsed {path.split('/deploy/')[-1]}: {kinds}", file=sys.stderr)
    except yaml.YAMLError as e:
        print(f"  YAML error in {path}: {e}", file=sys.stderr)
        bad = 1
sys.exit(bad)
PY

# 2 and 3. Every kustomization builds and its objects validate.
out=$(mktemp -d)
trap 'rm -rf -- "$out"' EXIT
mapfile -t kdirs < <(find "$K8S_DIR" -name kustomization.yaml -exec dirname {} \; | sort)
for d in "${kdirs[@]}"; do
  rel=${d#"$K8S_DIR"}
  name=k8s${rel//\//-}
  if ! build "$d" >"$out/$name.yaml" 2>"$out/$name.err"; then
    say "FAIL: kustomize build of deploy/k8s$rel: $(cat "$out/$name.err")"
    failed=1
    continue
  fi
  say "built deploy/k8s$rel: $(grep -c '^kind:' "$out/$name.yaml") objects"
  for v in 1.28.0 ""; do
    args=(--strict --quiet)
    [[ -z $v ]] || args+=(-k "$v")
    if ! "$VENV/bin/kubernetes-validate" "${args[@]}" "$out/$name.yaml" >"$out/$name.val" 2>&1; then
      say "FAIL: deploy/k8s$rel against Kubernetes ${v:-latest known}:"
      cat "$out/$name.val" >&2
      failed=1
    elif [[ -s $out/$name.val ]]; then
      say "warnings for deploy/k8s$rel (Kubernetes ${v:-latest}):"
      cat "$out/$name.val" >&2
    fi
  done
done
if ((failed)); then
  say "FAIL"
  exit 1
fi
say "OK: every manifest parses, every kustomization builds, every object validates (strict)"
