#!/usr/bin/env bash
# Builds Tessera's container image without pulling anything from a container registry: a
# Debian base made from Debian's package archive with mmdebstrap (ca-certificates and curl, for
# https:// servers and the health check), the release binaries built here with cargo, and
# deploy/Containerfile.prebuilt (the runtime stage of deploy/Containerfile, which builds from
# source on images pulled from a registry).
#
#   deploy/build-image.sh [--tag IMAGE] [--suite SUITE] [--no-cargo] [--refresh-base]
#   deploy/build-image.sh --check
#
# Needs podman, mmdebstrap (apt-get install podman mmdebstrap runc), root or podman's rootless
# setup, and cargo (unless --no-cargo: then the binaries already in target/release are used).
#   --tag IMAGE      the image to build (default localhost/tessera:latest)
#   --suite SUITE    the Debian release of the base (default: this host's, from /etc/os-release:
#                    the binaries are linked against the host's glibc, and the base's must be
#                    at least as new)
#   --no-cargo       do not run cargo build --release; use the binaries already built
#   --refresh-base   make the base again (for Debian's updates) instead of using the cached one
#   --check          only make sure the base exists and that podman can run a container from
#                    it; print nothing when podman's defaults work, or the line
#                      export CONTAINERS_CONF=.../deploy/podman-containers.conf
#                    when this host needs that file (use: eval "$(deploy/build-image.sh --check)").
#                    Exits 1, saying why, when no container runs.
#
# The base is cached by suite and package list in ${XDG_CACHE_HOME:-~/.cache}/tessera/ (the
# mmdebstrap tarball) and as the local image localhost/tessera-base:SUITE. Everything but the
# --check line goes to stderr.
set -euo pipefail
deploy=$(cd "$(dirname "$0")" && pwd)
repo=$(dirname "$deploy")

tag=localhost/tessera:latest
suite=
cargo_build=1
refresh=0
check=0
while [ $# -gt 0 ]; do
    case "$1" in
        --tag) tag=$2; shift 2 ;;
        --suite) suite=$2; shift 2 ;;
        --no-cargo) cargo_build=0; shift ;;
        --refresh-base) refresh=1; shift ;;
        --check) check=1; shift ;;
        -h|--help) sed -n '2,/^set -euo/p' "$0" | sed '$d; s/^# \{0,1\}//'; exit 0 ;;
        *) echo "build-image.sh: unknown argument $1 (see --help)" >&2; exit 2 ;;
    esac
done
say() { echo "build-image.sh: $*" >&2; }
die() { say "$*"; exit 1; }

for tool in podman mmdebstrap; do
    command -v "$tool" >/dev/null || die "$tool is not installed (apt-get install podman mmdebstrap runc)"
done
if [ -z "$suite" ]; then
    # shellcheck disable=SC1091
    suite=$(. /etc/os-release 2>/dev/null && [ "${ID:-}" = debian ] && echo "${VERSION_CODENAME:-}") || true
    [ -n "$suite" ] || die "this host is not Debian: name the Debian release whose glibc suits the binaries with --suite (e.g. --suite bookworm)"
fi

# ---- the base: mmdebstrap, cached ------------------------------------------------------------
# minbase (dpkg, apt, the essential set) plus what the image needs; merged /usr without the
# usrmerge package (and the perl it pulls in); no manuals, translations or docs but licences.
mmdebstrap_args=(
    --variant=minbase
    --include=ca-certificates,curl
    --hook-dir=/usr/share/mmdebstrap/hooks/merged-usr
    --dpkgopt='path-exclude=/usr/share/man/*'
    --dpkgopt='path-exclude=/usr/share/info/*'
    --dpkgopt='path-exclude=/usr/share/locale/*'
    --dpkgopt='path-include=/usr/share/locale/locale.alias'
    --dpkgopt='path-exclude=/usr/share/doc/*'
    --dpkgopt='path-include=/usr/share/doc/*/copyright'
)
key=$(printf '%s\n' "$suite" "${mmdebstrap_args[@]}" | sha256sum | cut -c1-12)
base=localhost/tessera-base:$suite
cache=${XDG_CACHE_HOME:-$HOME/.cache}/tessera
tarball=$cache/debian-$suite-$key.tar
label=org.tessera.base-key

have_key=$(podman image inspect --format "{{index .Config.Labels \"$label\"}}" "$base" 2>/dev/null || true)
if [ "$refresh" = 1 ] || [ "$have_key" != "$key" ]; then
    if [ "$refresh" = 1 ] || [ ! -s "$tarball" ]; then
        mkdir -p "$cache"
        say "making the $suite base with mmdebstrap (from Debian's archive) into $tarball"
        start=$(date +%s)
        mmdebstrap --format=tar "${mmdebstrap_args[@]}" "$suite" "$tarball.part" >&2
        mv "$tarball.part" "$tarball"
        say "base made in $(($(date +%s) - start)) s"
    fi
    say "importing $tarball as $base"
    podman import --change "LABEL $label=$key" "$tarball" "$base" >/dev/null
fi

# ---- can podman run a container here? -------------------------------------------------------
conf=
probe() { podman run --rm --pull=never --network=none "$base" true 2>&1; }
if ! out=$(probe); then
    if [ -n "${CONTAINERS_CONF:-}" ]; then
        die "podman cannot run a container (with CONTAINERS_CONF=$CONTAINERS_CONF): $out"
    fi
    conf=$deploy/podman-containers.conf
    if ! out2=$(CONTAINERS_CONF=$conf probe); then
        die "podman cannot run a container: $out; with CONTAINERS_CONF=$conf: $out2"
    fi
    export CONTAINERS_CONF=$conf
    say "podman's defaults cannot run a container here ($out); using $conf (export CONTAINERS_CONF=$conf to run the image)"
fi
if [ "$check" = 1 ]; then
    [ -z "$conf" ] || echo "export CONTAINERS_CONF=$conf"
    exit 0
fi

# ---- the binaries, built here ----------------------------------------------------------------
target=${CARGO_TARGET_DIR:-$repo/target}
if [ "$cargo_build" = 1 ]; then
    say "cargo build --release (tessera-server, tessera-worker, tessera)"
    (cd "$repo" && cargo build --release --locked -p tessera-server -p tessera-worker -p tessera-client >&2)
fi
ctx=$(mktemp -d "${TMPDIR:-/tmp}/tessera-image.XXXXXX")
trap 'rm -rf "$ctx"' EXIT
for bin in tessera-server tessera-worker tessera; do
    [ -x "$target/release/$bin" ] || die "$target/release/$bin is missing (cargo build --release, or drop --no-cargo)"
    cp "$target/release/$bin" "$ctx/"
done
cp "$deploy/image-setup.sh" "$ctx/"

# ---- the image ---------------------------------------------------------------------------------
# --format docker keeps the HEALTHCHECK (the OCI format has none); --pull=never: the base is local.
say "building $tag on $base"
podman build --pull=never --format docker --build-arg "BASE=$base" \
    -f "$deploy/Containerfile.prebuilt" -t "$tag" "$ctx" >&2
say "built $tag: $(podman image inspect --format '{{.Size}}' "$tag") bytes"
