#!/usr/bin/env bash
# Builds the texsyn image without a registry: the release binaries built on this
# machine and the shared libraries they load (found with ldd), over `FROM scratch`.
# No base image is pulled, so it works on a machine with no registry access.
#
#   cargo build --release --bin texsyn --bin texsyn-worker
#   deploy/docker/build-offline.sh [TAG]        # TAG defaults to texsyn:latest
#
# BIN_DIR overrides where the binaries are taken from (default target/release).
set -euo pipefail
root=$(cd "$(dirname "$0")/../.." && pwd)
tag=${1:-texsyn:latest}
bin_dir=${BIN_DIR:-$root/target/release}
for b in texsyn texsyn-worker; do
    if [ ! -x "$bin_dir/$b" ]; then
        echo "build-offline: $bin_dir/$b not found; run 'cargo build --release --bin texsyn --bin texsyn-worker' first (or set BIN_DIR)" >&2
        exit 1
    fi
done
command -v ldd >/dev/null || { echo "build-offline: ldd not found (install libc-bin)" >&2; exit 1; }

ctx=$(mktemp -d)
trap 'rm -rf "$ctx"' EXIT
fs=$ctx/rootfs
install -d "$fs/usr/local/bin" "$fs/etc" "$fs/run/secrets" "$fs/out" "$fs/usr/local/share/texsyn"
install -d -m 1777 "$fs/tmp"
for b in texsyn texsyn-worker; do
    # Stripped: the debug info of the release profile is most of the file.
    install -m 0755 -s "$bin_dir/$b" "$fs/usr/local/bin/$b"
    # Every library the loader maps (absolute paths in ldd's output), the
    # loader itself included, at its own path; symlinks are resolved.
    ldd "$bin_dir/$b" | grep -o '/[^ ]*' | while read -r lib; do
        install -D -m 0755 "$(readlink -f "$lib")" "$fs$lib"
    done
done
# Names for uid/gid 10001, so tools inside and `docker top` show a user name.
printf 'root:x:0:0:root:/nonexistent:/sbin/nologin\ntexsyn:x:10001:10001:texsyn:/nonexistent:/sbin/nologin\n' >"$fs/etc/passwd"
printf 'root:x:0:\ntexsyn:x:10001:\n' >"$fs/etc/group"
cp -r "$root/assets/textures" "$fs/usr/local/share/texsyn/textures"
chown 10001:10001 "$fs/out" 2>/dev/null || chmod 1777 "$fs/out"
cp "$root/deploy/docker/Dockerfile.offline" "$ctx/Dockerfile"
if ! docker build -q -t "$tag" "$ctx" >"$ctx/build.log" 2>&1; then
    cat "$ctx/build.log" >&2
    exit 1
fi
echo "built $tag ($(docker image inspect -f '{{.Size}}' "$tag") bytes)"
