#!/bin/sh
# Regenerate the tables of docs/third-party.md: run each player, built as its build.sh says, on the
# committed suites and write the causes `fbaconf explain` finds (and confirms, in the sandbox) into
# the document's generated blocks.
#   examples/third-party/tables.sh XFACE_OUTDIR GRETA_OUTDIR
set -eu
HERE=$(cd "$(dirname "$0")" && pwd)
DOC="$HERE/../../docs/third-party.md"
W=$(mktemp -d)
trap 'rm -rf "$W"' EXIT
one() {  # NAME MANIFEST [fbaconf run options]
    name=$1 manifest=$2
    shift 2
    # a player fails cases: the run's exit code says so; what counts is that it wrote its report
    fbaconf run --decoder "$manifest" -j 2 -o "$W/$name" "$@" > "$W/$name.log" 2>&1 || true
    [ -f "$W/$name/report.json" ] || { cat "$W/$name.log" >&2; exit 2; }
    fbaconf explain "$W/$name" --write-doc "$DOC" "$@"
}
one xface "$1/xface.toml"
one greta "$2/greta.toml" --sandbox-ro /usr/lib/jvm
echo "wrote $DOC"
