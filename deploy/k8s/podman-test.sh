#!/usr/bin/env bash
# The Kubernetes manifests run, not only validated: the image of deploy/docker/ built without
# any registry, then the learner, the optimiser and the actors played from `kubectl kustomize
# deploy/k8s` with `podman kube play`, with the Secrets of make-secrets.sh. Checks: the probes'
# endpoint answers, the run goes on, the learner pod deleted mid-run comes back (played again,
# as its Deployment would recreate it) and resumes from its volume, the run completes, and its
# rows equal those of the same config run once in one process (lock-step is deterministic).
#
#   deploy/k8s/podman-test.sh [--designs N] [--keep] [COADAPT_BIN]
#
# The image: a Debian bookworm root filesystem made by mmdebstrap from Debian's packages
# (ca-certificates, tini, the coadapt user), imported as localhost/coadapt-base:bookworm, then
# deploy/docker/Containerfile.offline (the Dockerfile's runtime stage) with COADAPT_BIN, which
# must be built on Debian bookworm (the image's glibc).
#
# What podman (Debian 12: 4.3.1) and this kind of sandbox need, and why:
# - the OCI runtime is runc, and every container's open-files and process limits are set at
#   or below the current hard limits (containers.conf default_ulimits): podman's defaults raise
#   them, which takes CAP_SYS_RESOURCE, which a container sandbox lacks ("setrlimit
#   RLIMIT_NOFILE: Operation not permitted"); crun also refuses a hybrid cgroup hierarchy whose
#   v2 side has a controller ("cgroups in hybrid mode not supported");
# - podman has no Services: the learner's pod joins the pods' network with the Service's name
#   (coadapt-learner) as its DNS alias, and the NetworkPolicy is left out;
# - podman 4.3 writes a Secret's `data` values to files without base64-decoding them, and
#   crashes on a secret volume without `optional` (podman issue 16636): the Secrets are created
#   (`podman secret create`) with decoded values, and `optional: false` (Kubernetes' default) is
#   written out;
# - podman runs probes through systemd timers (none here) and turns an httpGet on a named port
#   into `curl http://localhost:0/...`: this script does what the kubelet does, an HTTP GET of
#   /healthz on the learner's metrics port.
# Exit: 0 pass; 1 fail; 2 usage; 77 skipped (why is printed).
set -euo pipefail

SCRIPT_DIR=$(cd -- "$(dirname -- "${BASH_SOURCE[0]}")" && pwd)
REPO_ROOT=$(cd -- "$SCRIPT_DIR/../.." && pwd)
say() { printf '[k8s-podman %s] %s\n' "$(date +%H:%M:%S)" "$*" >&2; }
fail() { say "FAIL: $*"; exit 1; }
skip() { say "SKIP: $*"; exit 77; }
usage_err() { printf 'podman-test.sh: %s\n' "$*" >&2; exit 2; }

bin=${COADAPT_BIN:-}
designs=40
keep=0
timeout=900
while [[ $# -gt 0 ]]; do
  case $1 in
    -h | --help) sed -n '2,30p' "$0" | sed 's/^# \{0,1\}//'; exit 0 ;;
    --designs) [[ $# -ge 2 && $2 =~ ^[1-9][0-9]*$ ]] || usage_err "--designs needs a count"; designs=$2; shift 2 ;;
    --keep) keep=1; shift ;;
    --timeout) [[ $# -ge 2 && $2 =~ ^[0-9]+$ ]] || usage_err "--timeout needs seconds"; timeout=$2; shift 2 ;;
    -*) usage_err "unknown option '$1'" ;;
    *) bin=$1; shift ;;
  esac
done
[[ -n $bin ]] || bin=$REPO_ROOT/target/release/coadapt
[[ -x $bin ]] || usage_err "no coadapt binary at '$bin'"

[[ $(uname -s) == Linux ]] || skip "podman needs Linux"
[[ $EUID -eq 0 ]] || skip "needs root (rootful podman)"
grep -qs 'bookworm\|^12' /etc/debian_version /etc/os-release || skip "the image's binary is built here and must link Debian bookworm's glibc"
missing=()
for tool in podman runc mmdebstrap; do command -v "$tool" >/dev/null 2>&1 || missing+=("$tool"); done
command -v kubectl >/dev/null 2>&1 || missing+=(kubernetes-client)
python3 -c 'import yaml' 2>/dev/null || missing+=(python3-yaml)
if ((${#missing[@]})); then
  command -v apt-get >/dev/null 2>&1 || skip "missing ${missing[*]} and no apt-get to install them"
  say "installing ${missing[*]} (apt-get)"
  export DEBIAN_FRONTEND=noninteractive
  apt-get install -y -q "${missing[@]}" >/tmp/coadapt-podman-apt.log 2>&1 ||
    { apt-get update -q >>/tmp/coadapt-podman-apt.log 2>&1 && apt-get install -y -q "${missing[@]}" >>/tmp/coadapt-podman-apt.log 2>&1; } ||
    skip "apt-get could not install ${missing[*]} (see /tmp/coadapt-podman-apt.log)"
fi

work=$(mktemp -d "${TMPDIR:-/tmp}/coadapt-k8s.XXXXXX")
net=coadapt-k8s-$$
export CONTAINERS_CONF=$work/containers.conf
nofile=$(ulimit -Hn) nproc=$(ulimit -Hu)
# (16384 at most: here a process limit of 65536, under the shell's hard limit, was still refused
# by runc's init, whose own limits podman's conmon sets.)
[[ $nofile == unlimited || $nofile -gt 16384 ]] && nofile=16384
[[ $nproc == unlimited || $nproc -gt 16384 ]] && nproc=16384
cat >"$CONTAINERS_CONF" <<EOF
[containers]
default_ulimits = ["nofile=$nofile:$nofile", "nproc=$nproc:$nproc"]
[engine]
runtime = "runc"
EOF
passed=0
cleanup() {
  local st=$?
  trap - EXIT INT TERM
  if [[ -f $work/learner.yaml ]]; then
    podman kube down "$work/others.yaml" >/dev/null 2>&1 || true
    podman kube down "$work/learner.yaml" >/dev/null 2>&1 || true
  fi
  # A pod whose creation failed half-way (seen: coadapt-actor-pod-3, "Created", no containers)
  # is not taken down by `kube down`; remove every pod the manifests name.
  podman pod ls --format '{{.Name}}' 2>/dev/null | grep '^coadapt-' | xargs -r podman pod rm -f -t 0 >/dev/null 2>&1 || true
  for v in coadapt-runs coadapt-optimizer-state coadapt-config coadapt-tls coadapt-tokens coadapt-actor-token coadapt-optimizer-token tmp state tls token config runs; do
    podman volume rm -f "$v" >/dev/null 2>&1 || true
  done
  for s in coadapt-tls coadapt-tokens coadapt-actor-token coadapt-optimizer-token; do podman secret rm "$s" >/dev/null 2>&1 || true; done
  podman network rm -f "$net" >/dev/null 2>&1 || true
  if ((passed && !keep)); then rm -rf -- "$work"; else say "work directory kept: $work"; fi
  exit "$st"
}
trap cleanup EXIT
trap 'say "interrupted"; exit 130' INT TERM

# Anything left by an earlier run of these manifests would be reused: refuse instead.
if podman pod exists coadapt-learner-pod-0 2>/dev/null || podman volume exists coadapt-runs 2>/dev/null; then
  fail "podman already has a coadapt-learner pod or a coadapt-runs volume (podman kube down, podman volume rm coadapt-runs)"
fi
# The optimiser's state volume alone (no learner) is debris too: its state would answer a new run.
podman volume rm -f coadapt-optimizer-state >/dev/null 2>&1 || true
# Without a learner, other coadapt pods are the debris of a run that died before its cleanup
# (a half-created pod keeps its name and makes `kube play` fail with "pod already exists").
for p in $(podman pod ls --format '{{.Name}}' 2>/dev/null | grep '^coadapt-' || true); do
  say "removing the stale pod $p (no learner pod: left by an earlier run)"
  podman pod rm -f -t 0 "$p" >/dev/null 2>&1 || fail "could not remove the stale pod $p"
done

# --- the image, without a registry -----------------------------------------------------------------
if ! podman image exists localhost/coadapt-base:bookworm; then
  say "making the base image: mmdebstrap bookworm (ca-certificates, tini, user coadapt 10001)"
  # shellcheck disable=SC2016 # $1 is mmdebstrap's, in the hook
  mmdebstrap --variant=minbase --include=ca-certificates,tini \
    --customize-hook='chroot "$1" groupadd --system --gid 10001 coadapt' \
    --customize-hook='chroot "$1" useradd --system --uid 10001 --gid coadapt --home-dir /var/lib/coadapt --create-home --shell /usr/sbin/nologin coadapt' \
    bookworm "$work/base.tar" >"$work/mmdebstrap.log" 2>&1 || fail "mmdebstrap failed (see $work/mmdebstrap.log)"
  podman import "$work/base.tar" localhost/coadapt-base:bookworm >/dev/null || fail "podman import failed"
  rm -f "$work/base.tar"
fi
mkdir -p "$work/context"
cp "$bin" "$work/context/coadapt"
cp -r "$REPO_ROOT/configs" "$work/context/configs"
podman build -q -f "$REPO_ROOT/deploy/docker/Containerfile.offline" -t localhost/coadapt:dev "$work/context" >"$work/build.log" 2>&1 ||
  fail "podman build failed (see $work/build.log)"
out=$(podman run --rm localhost/coadapt:dev --version 2>&1) || skip "containers cannot start here: $out"
say "image localhost/coadapt:dev: $out"

# --- the manifests, as podman plays them -----------------------------------------------------------
"$REPO_ROOT/deploy/k8s/make-secrets.sh" --out "$work/secrets" --bin "$bin" 2>>"$work/secrets.log" || fail "make-secrets.sh failed"
kubectl kustomize "$REPO_ROOT/deploy/k8s" >"$work/rendered.yaml" 2>"$work/kustomize.err" ||
  skip "kubectl kustomize deploy/k8s failed (a kubectl older than 1.21 has a kustomize without 'labels:'): $(head -c 300 "$work/kustomize.err")"
python3 - "$work" "$designs" <<'PY' || fail "could not prepare the manifests for podman"
import base64, json, re, sys, yaml
work, designs = sys.argv[1], int(sys.argv[2])
docs = list(yaml.safe_load_all(open(f"{work}/rendered.yaml")))
for d in docs:
    if d["kind"] == "ConfigMap":
        # A longer run than the manifests' tiny one, so that the learner pod can be deleted mid-run.
        toml = d["data"]["run.toml"]
        toml, n = re.subn(r"(?m)^designs = \d+$", f"designs = {designs}", toml)
        assert n == 1, "run.toml has no single designs line"
        d["data"]["run.toml"] = toml
        open(f"{work}/run.toml", "w").write(toml)
    if d["kind"] == "Deployment":
        for v in d["spec"]["template"]["spec"].get("volumes", []):
            if "secret" in v:
                v["secret"].setdefault("optional", False)
kinds = {d["kind"] for d in docs}
assert {"ConfigMap", "PersistentVolumeClaim", "Deployment"} <= kinds, kinds
learner = [d for d in docs if d["kind"] == "Deployment" and d["metadata"]["name"] == "coadapt-learner"]
others = [d for d in docs if d["kind"] == "Deployment" and d["metadata"]["name"] != "coadapt-learner"]
cm = [d for d in docs if d["kind"] == "ConfigMap"]
pvc = [d for d in docs if d["kind"] == "PersistentVolumeClaim"]
assert len(learner) == 1 and len(others) == 2, [d["metadata"]["name"] for d in docs]
yaml.safe_dump_all(cm + pvc + learner, open(f"{work}/learner.yaml", "w"))
yaml.safe_dump_all(cm + learner, open(f"{work}/learner-again.yaml", "w"))  # the claim exists by then
yaml.safe_dump_all(cm + others, open(f"{work}/others.yaml", "w"))
for s in yaml.safe_load_all(open(f"{work}/secrets/secrets.yaml")):
    s["data"] = {k: base64.b64decode(v).decode() for k, v in s["data"].items()}
    json.dump(s, open(f"{work}/secret-{s['metadata']['name']}.json", "w"))
PY
for f in "$work"/secret-*.json; do
  name=${f##*/secret-}
  podman secret create "${name%.json}" "$f" >/dev/null || fail "podman secret create ${name%.json} failed"
done
podman network create "$net" >/dev/null || fail "podman network create failed"

play() { # play FILE [alias]: podman kube play on our network
  local netarg=$net
  [[ -z ${2:-} ]] || netarg="$net:alias=$2"
  podman kube play --network "$netarg" "$1" >"$work/play-$(basename "$1").log" 2>&1 ||
    fail "podman kube play $1 failed: $(grep -v '^\s' "$work/play-$(basename "$1").log" | tail -n 3)"
}
probe() { # the kubelet's httpGet: /healthz on the learner's metrics port (published by the pod)
  python3 -c 'import sys,urllib.request; r = urllib.request.urlopen("http://127.0.0.1:9464/healthz", timeout=3); print(r.status, r.read().decode().strip())' 2>/dev/null
}
episodes() { podman exec coadapt-learner-pod-0-learner sh -c 'wc -l < /var/lib/coadapt/run/episodes.csv' 2>/dev/null || echo 0; }
wait_probe() {
  local deadline=$((SECONDS + 90)) got
  until got=$(probe) && [[ $got == "200 "* ]]; do
    ((SECONDS < deadline)) || fail "the learner's /healthz did not answer within 90 s: $(podman logs --tail 5 coadapt-learner-pod-0-learner 2>&1)"
    sleep 1
  done
  say "probe: GET /healthz on the metrics port: $got"
}

play "$work/learner.yaml" coadapt-learner
wait_probe
play "$work/others.yaml"
say "playing: $(podman ps --format '{{.Names}}' | grep -c -- '-pod-') pod containers ($(podman ps --format '{{.Names}}' | grep -v infra | tr '\n' ' '))"

# --- delete the learner pod mid-run; its Deployment would make a new one on the same claim ----------
deadline=$((SECONDS + timeout))
until (($(episodes) > 20)); do
  ((SECONDS < deadline)) || fail "the run made no progress: $(podman logs --tail 5 coadapt-learner-pod-0-learner 2>&1)"
  sleep 1
done
before=$(episodes)
podman pod rm -f -t 0 coadapt-learner-pod-0 >/dev/null || fail "could not delete the learner pod"
say "learner pod deleted at episode $((before - 1))"
play "$work/learner-again.yaml" coadapt-learner
wait_probe
# The log is read whole first: `podman logs | grep -q` under pipefail fails when grep stops at
# its match and podman, still writing, gets SIGPIPE (it did, with "resuming" in the log).
learner_log=$(podman logs coadapt-learner-pod-0-learner 2>&1)
grep -q "resuming" <<< "$learner_log" || fail "the new learner pod did not resume: $(head -n 12 <<< "$learner_log")"
say "the new learner pod resumed: $(podman logs coadapt-learner-pod-0-learner 2>&1 | grep -m1 resuming | cut -c1-160)"

# --- the end ------------------------------------------------------------------------------------------
while [[ $(podman inspect -f '{{.State.Status}}' coadapt-learner-pod-0-learner 2>/dev/null) == running ]]; do
  ((SECONDS < deadline)) || fail "the run did not finish within ${timeout}s"
  sleep 2
done
status=$(podman inspect -f '{{.State.ExitCode}}' coadapt-learner-pod-0-learner)
summary=$(podman logs coadapt-learner-pod-0-learner 2>/dev/null | tail -n 1)
((status == 0)) || fail "the learner exited with $status: $(podman logs --tail 5 coadapt-learner-pod-0-learner 2>&1)"
[[ $summary == *'"interrupted":false'* ]] || fail "no summary of a finished run: $summary"
say "the learner finished: $(cut -c1-200 <<<"$summary")"
mkdir -p "$work/run"
cp /var/lib/containers/storage/volumes/coadapt-runs/_data/run/{designs,episodes}.csv "$work/run/" 2>/dev/null ||
  podman volume export coadapt-runs | tar -x -C "$work/run" --strip-components=1 run/designs.csv run/episodes.csv ||
  fail "cannot read the run directory from the coadapt-runs volume"
"$bin" run --config "$work/run.toml" --transport in-process --out "$work/undisturbed" >"$work/undisturbed.out" 2>"$work/undisturbed.err" ||
  fail "the undisturbed in-process run failed (see $work/undisturbed.err)"
python3 "$REPO_ROOT/deploy/compare_runs.py" "$work/run" "$work/undisturbed" "$designs" || fail "the rows differ from the undisturbed run's"
for tok in "$work"/secrets/*.token; do
  for c in $(podman ps -a --format '{{.Names}}' | grep -v infra); do
    log=$(podman logs "$c" 2>&1)
    if grep -qF -- "$(<"$tok")" <<< "$log"; then fail "a token ($tok) appears in the log of $c"; fi
  done
done
# The optimiser kept its state on its claim (optimizer-pvc.yaml), not in the pod.
mp=$(podman volume inspect coadapt-optimizer-state --format '{{.Mountpoint}}' 2>/dev/null) ||
  fail "no coadapt-optimizer-state volume: the optimiser's state is not on its claim"
[[ -n $(ls -A "$mp" 2>/dev/null) ]] || fail "the optimiser wrote no state to its volume ($mp)"
say "the optimiser's state is on its claim: $(ls -A "$mp" | tr '\n' ' ')"
passed=1
say "PASS: the manifests ran a co-adaptation in podman: probes answered, the deleted learner pod resumed from its volume, rows equal the undisturbed run's"
