#!/usr/bin/env bash
# Sets up everything `make demo` and `make test` need, on a fresh Debian/Ubuntu machine:
# python3.11, the Mesa EGL libraries and a .venv with the pinned requirements.
# A second run only checks (a few hundred milliseconds): nothing is reinstalled.
set -euo pipefail
cd "$(dirname "$0")/.."

die() { echo "setup: $*" >&2; exit 1; }
as_root() { [ "$(id -u)" = 0 ]; }
apt_install() {
    if as_root && command -v apt-get >/dev/null; then
        echo "setup: installing $* with apt-get"
        export DEBIAN_FRONTEND=noninteractive
        apt-get update -qq >/dev/null && apt-get install -y -qq "$@" >/dev/null
    else
        die "missing system packages; run: sudo apt-get install -y $*"
    fi
}

# 1. python3.11 (bpy from PyPI is built for CPython 3.11 only)
PY=""
for cand in "${PYTHON311:-}" python3.11 python3; do
    [ -n "$cand" ] || continue
    if command -v "$cand" >/dev/null && "$cand" -c 'import sys; sys.exit(sys.version_info[:2] != (3, 11))' 2>/dev/null; then
        PY=$(command -v "$cand"); break
    fi
done
if [ -z "$PY" ]; then
    if as_root && command -v apt-get >/dev/null && apt-cache show python3.11 >/dev/null 2>&1; then
        apt_install python3.11 python3.11-venv
        PY=$(command -v python3.11)
    else
        die "python3.11 not found (bpy is cp311-only). Install it: 'sudo apt-get install python3.11 python3.11-venv' (Debian 12 / Ubuntu 22.04+), or 'pyenv install 3.11', or set PYTHON311=/path/to/python3.11."
    fi
fi

# 2. Mesa EGL (moderngl's headless context; bpy aborts without it)
missing=()
ldconfig -p 2>/dev/null | grep -q 'libEGL.so.1 ' || missing+=(libegl1)
ldconfig -p 2>/dev/null | grep -q 'libGL.so.1 ' || missing+=(libgl1)
compgen -G '/usr/lib/*/dri/swrast_dri.so' >/dev/null || compgen -G '/usr/lib*/dri/swrast_dri.so' >/dev/null || missing+=(libgl1-mesa-dri)
if [ ${#missing[@]} -gt 0 ]; then
    apt_install libegl1 libgl1-mesa-dri libgl1
fi

# 3. the virtual environment with the pinned requirements
stamp=.venv/.requirements.sha256
want=$(sha256sum requirements.txt | cut -d' ' -f1)
if [ -x .venv/bin/python ] && [ -f "$stamp" ] && [ "$(cat "$stamp")" = "$want" ]; then
    exit 0
fi
if [ ! -x .venv/bin/python ]; then
    echo "setup: creating .venv with $PY"
    if ! "$PY" -m venv .venv 2>/dev/null; then
        rm -rf .venv
        if as_root && command -v apt-get >/dev/null; then
            apt_install python3.11-venv
            "$PY" -m venv .venv
        else
            die "'$PY -m venv' failed; run: sudo apt-get install -y python3.11-venv"
        fi
    fi
fi
echo "setup: installing requirements.txt into .venv (bpy is a ~370 MB download the first time)"
quiet() { "$@" 2> >(grep -v 'is ignored: it is neither a file nor a directory' >&2); }  # (local mirror noise)
quiet .venv/bin/python -m pip install -q --disable-pip-version-check --upgrade pip >/dev/null
quiet .venv/bin/python -m pip install -q --disable-pip-version-check -r requirements.txt
echo "$want" > "$stamp"
echo "setup: done"
