#!/bin/sh
# Compiles the C# binding and its test with Mono's mcs into OUTDIR and runs
# it with mono (ctest's Binding.CSharp, under tests/with_server.py; the
# library is found through LD_LIBRARY_PATH). Exit 77 (ctest: skipped) when
# Mono is not installed: scripts/setup.sh installs mono-mcs and mono-runtime.
set -eu
out=${1:?usage: run_test.sh OUTDIR}
here=$(cd "$(dirname "$0")" && pwd)
for tool in mcs mono; do
  if ! command -v "$tool" >/dev/null 2>&1; then
    echo "run_test.sh: SKIPPED: $tool is not installed (bash scripts/setup.sh installs mono-mcs and mono-runtime)" >&2
    exit 77
  fi
done
mkdir -p "$out"
mcs -nologo -warnaserror -unsafe -out:"$out/progskin_test.exe" "$here/Progskin.cs" "$here/ProgskinTest.cs"
exec mono "$out/progskin_test.exe"
