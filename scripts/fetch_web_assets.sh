#!/usr/bin/env bash
# Reproduce src/freqbrdf/web/: the pinned <model-viewer> web component used by the HTML report.
# Its UMD build bundles its dependencies (three.js, lit), so one classic <script> works from file://
# (ES modules do not load from file:// in Chromium).
set -euo pipefail
VERSION=4.4.0
here="$(cd "$(dirname "$0")/.." && pwd)"
work="$(mktemp -d)"
trap 'rm -rf "$work"' EXIT
(cd "$work" && npm pack --silent "@google/model-viewer@${VERSION}" >/dev/null && tar xzf google-model-viewer-${VERSION}.tgz)
cp "$work/package/dist/model-viewer-umd.min.js" "$here/src/freqbrdf/web/model-viewer-umd.min.js"
cp "$work/package/LICENSE" "$here/src/freqbrdf/web/LICENSE.model-viewer"
echo "model-viewer ${VERSION} copied into src/freqbrdf/web/"
