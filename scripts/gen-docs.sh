#!/usr/bin/env bash
# Regenerates the option tables in docs/configuration.md from the code's schema
# (`pp5echo config --markdown`); the text around the markers is kept.
# Usage: scripts/gen-docs.sh [BUILD_DIR]
set -euo pipefail
cd "$(dirname "$0")/.."
bin="${1:-build}/src/app/pp5echo"
doc=docs/configuration.md
begin='<!-- BEGIN GENERATED: pp5echo config --markdown -->'
end='<!-- END GENERATED -->'
tables=$(mktemp)
"$bin" config --markdown > "$tables"
awk -v b="$begin" -v e="$end" -v t="$tables" '
  $0 == b { print; while ((getline line < t) > 0) print line; skip = 1; next }
  $0 == e { skip = 0 }
  !skip { print }
' "$doc" > "$doc.new"
mv "$doc.new" "$doc"
rm -f "$tables"
echo "updated $doc"
