#!/usr/bin/env bash
# CTest view.template: the committed page template viewer/soma_view.html is up
# to date with its sources.
#  1. Always (no Node needed): the sources_hash the template records equals
#     the sha256 of the sources now (the same recipe as viewer/build.mjs:
#     sha256 of the `sha256sum` lines of build.mjs, package.json,
#     package-lock.json, src/* in byte order).
#  2. When Node and viewer/node_modules are there (`cd viewer && npm ci`):
#     a rebuild into a temporary file is byte-identical to the template.
#
#   bash tests/view/template_test.sh <source dir>
set -euo pipefail
src=${1:?usage: template_test.sh <source dir>}
cd "$src/viewer"

template=soma_view.html
[[ -f $template ]] || { echo "FAIL: $src/viewer/$template is missing (build it: cd viewer && npm ci && node build.mjs)"; exit 1; }
recorded=$(grep -o 'sources_hash=[0-9a-f]*' "$template" | head -1 | cut -d= -f2)
actual=$({
  sha256sum build.mjs package.json package-lock.json
  for f in $(LC_ALL=C ls src); do sha256sum "src/$f"; done
} | sha256sum | cut -d' ' -f1)
if [[ "$recorded" != "$actual" ]]; then
  echo "FAIL: viewer/$template was built from other sources (recorded sources_hash ${recorded:-none}, sources now $actual): rebuild it with: cd viewer && npm ci && node build.mjs"
  exit 1
fi
count=$(grep -o '__SOMA_VIEW_DATA__' "$template" | wc -l)
if [[ $count -ne 1 ]]; then
  echo "FAIL: viewer/$template holds the data placeholder $count times (expected once)"
  exit 1
fi
echo "ok: viewer/$template matches its sources (sources_hash $actual)"

if command -v node >/dev/null && [[ -d node_modules/three && -d node_modules/esbuild ]]; then
  tmp=$(mktemp -d)
  trap 'rm -rf "$tmp"' EXIT
  node build.mjs --out "$tmp/rebuilt.html" >/dev/null
  if ! cmp -s "$tmp/rebuilt.html" "$template"; then
    echo "FAIL: rebuilding viewer/$template from its sources gives different bytes: rebuild it with: cd viewer && node build.mjs"
    exit 1
  fi
  echo "ok: a rebuild is byte-identical"
else
  echo "note: no node or viewer/node_modules: the rebuild comparison was skipped"
fi
