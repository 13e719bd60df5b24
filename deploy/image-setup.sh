#!/bin/sh
# The runtime stage of both container builds (deploy/Containerfile, deploy/Containerfile.prebuilt)
# runs this as root inside the base image, so that the two images are set up the same way.
#   - ca-certificates: workers reaching an https:// server; curl: the health check. A base made
#     by deploy/build-image.sh (mmdebstrap) has both already; debian:bookworm-slim gets them here.
#   - the non-root user the farm runs as (uid and gid 10001), whose home is the /data volume.
set -eu
if ! command -v curl >/dev/null || [ ! -e /etc/ssl/certs/ca-certificates.crt ]; then
    apt-get update
    apt-get install -y --no-install-recommends ca-certificates curl
    rm -rf /var/lib/apt/lists/*
fi
groupadd --system --gid 10001 tessera
useradd --system --uid 10001 --gid tessera --home-dir /data --shell /usr/sbin/nologin tessera
mkdir -p /data
chown tessera:tessera /data
