#!/usr/bin/env bash
# Regenerate vendor/rapier3d.patch: the vendored rapier3d against the published crate of the
# same version (fetched into cargo's registry cache by a throwaway project).
#   bash vendor/update_patch.sh
set -euo pipefail
cd "$(dirname "$0")/.."
VERSION=$(sed -nE 's/^version = "([^"]+)"/\1/p' vendor/rapier3d/Cargo.toml | head -1)
TMP=$(mktemp -d)
trap 'rm -rf "$TMP"' EXIT
mkdir -p "$TMP/fetch/src"
printf '[package]\nname = "fetch"\nversion = "0.0.0"\nedition = "2021"\n[dependencies]\nrapier3d = "=%s"\n' "$VERSION" > "$TMP/fetch/Cargo.toml"
echo 'fn main() {}' > "$TMP/fetch/src/main.rs"
(cd "$TMP/fetch" && cargo fetch -q)
UPSTREAM=$(ls -d "${CARGO_HOME:-$HOME/.cargo}"/registry/src/*/rapier3d-"$VERSION" | head -1)
mkdir -p "$TMP/a" "$TMP/b"
cp -r "$UPSTREAM/src" "$TMP/a/src"
cp -r vendor/rapier3d/src "$TMP/b/src"
(cd "$TMP" && diff -ruN a/src b/src || true) | sed -E 's/^((\+\+\+|---) [^\t]+)\t.*/\1/' > vendor/rapier3d.patch
echo "wrote vendor/rapier3d.patch ($(grep -c '^+++' vendor/rapier3d.patch) files) against rapier3d $VERSION"
