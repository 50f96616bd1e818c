#!/usr/bin/env bash
# Debian packages freqbrdf needs at run time. Installs them when missing and we are root;
# otherwise prints exactly what to install and fails.
# With --test, also the optional test package `chromium` (the report's browser test): installed
# when possible, otherwise a note (that test then skips and says why).
set -euo pipefail

if [ "${1:-}" = "--test" ] && ! command -v chromium >/dev/null 2>&1; then
    if [ "$(id -u)" -eq 0 ] && command -v apt-get >/dev/null 2>&1; then
        echo "freqbrdf: installing chromium for the report's browser test"
        export DEBIAN_FRONTEND=noninteractive
        (apt-get update -qq && apt-get install -y -qq --no-install-recommends chromium) \
            || echo "freqbrdf: could not install chromium; the browser test will skip" >&2
    else
        echo "freqbrdf: optional: 'sudo apt-get install chromium' enables the report's browser test" >&2
    fi
fi

missing=()
# Mitsuba's CPU variant (llvm_ad_rgb) JIT-compiles with a system libLLVM >= 17.
# (compgen: one pattern that matches is enough; `ls` fails when any pattern matches nothing)
has_llvm=false
for pattern in '/usr/lib/*/libLLVM-1[7-9].so*' '/usr/lib/*/libLLVM-2[0-9].so*' '/usr/lib/libLLVM-1[7-9].so*'; do
    if compgen -G "$pattern" >/dev/null; then has_llvm=true; fi
done
if [ "$has_llvm" = false ]; then
    missing+=(libllvm19)
fi

if [ ${#missing[@]} -eq 0 ]; then
    exit 0
fi

if [ "$(id -u)" -eq 0 ] && command -v apt-get >/dev/null 2>&1; then
    echo "freqbrdf: installing Debian packages: ${missing[*]}"
    export DEBIAN_FRONTEND=noninteractive
    apt-get update -qq
    apt-get install -y -qq "${missing[@]}"
else
    echo "freqbrdf: missing system packages: ${missing[*]}" >&2
    echo "Install them with:  sudo apt-get install ${missing[*]}" >&2
    echo "(Mitsuba 3's CPU renderer needs libLLVM 17 or newer.)" >&2
    exit 1
fi
