#!/usr/bin/env bash
# Fails (and names the files) if any C++ source under the project differs from what
# clang-format makes of it with the project's .clang-format. Fix: clang-format -i FILE.
set -euo pipefail
root="$(cd "$(dirname "$0")/.." && pwd)"
clang_format="${1:-clang-format}"
cd "$root"
mapfile -t files < <(find bench client lcmtypes robust server solvers tests tools \
  -type f \( -name '*.cpp' -o -name '*.h' \) -not -path '*/build*' | sort)
((${#files[@]})) || { echo "check-format: no sources found under $root" >&2; exit 1; }
bad=()
for f in "${files[@]}"; do
  "$clang_format" --style=file --dry-run --Werror "$f" >/dev/null 2>&1 || bad+=("$f")
done
if ((${#bad[@]})); then
  printf 'check-format: %d of %d files are not clang-formatted:\n' "${#bad[@]}" "${#files[@]}" >&2
  printf '  %s\n' "${bad[@]}" >&2
  exit 1
fi
echo "check-format: ${#files[@]} files follow .clang-format"
