#!/usr/bin/env bash
# Node tools of the test suite: the Khronos glTF validator (npm `gltf-validator`, pinned with its
# integrity hash in tests/node/package-lock.json), installed into the project-local, git-ignored
# folder .cache/node. Node.js and npm come from Debian when missing and we are root. Never fails:
# without them the validator test skips and says why.
set -uo pipefail

root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
target="$root/.cache/node"

if ! command -v npm >/dev/null 2>&1; then
    if [ "$(id -u)" -eq 0 ] && command -v apt-get >/dev/null 2>&1; then
        echo "freqbrdf: installing nodejs and npm for the glTF validator test"
        export DEBIAN_FRONTEND=noninteractive
        (apt-get update -qq && apt-get install -y -qq --no-install-recommends nodejs npm) \
            || echo "freqbrdf: could not install nodejs and npm; the glTF validator test will skip" >&2
    else
        echo "freqbrdf: optional: 'sudo apt-get install nodejs npm' enables the glTF validator test" >&2
    fi
fi
if ! command -v npm >/dev/null 2>&1; then
    exit 0
fi

# Up to date when the installed lock file is the pinned one.
if cmp -s "$root/tests/node/package-lock.json" "$target/package-lock.json" \
        && [ -f "$target/node_modules/gltf-validator/package.json" ]; then
    exit 0
fi
mkdir -p "$target"
cp "$root/tests/node/package.json" "$root/tests/node/package-lock.json" "$target/"
echo "freqbrdf: installing the glTF validator into .cache/node"
(cd "$target" && npm ci --no-audit --no-fund --loglevel=error >/dev/null) \
    || echo "freqbrdf: could not install gltf-validator; the glTF validator test will skip" >&2
exit 0
