#!/bin/sh
# Build fbaconf's Greta adapter OUTSIDE the repository and write its manifest there.
#   examples/third-party/greta/build.sh GRETA_CHECKOUT OUTDIR
# GRETA_CHECKOUT: a checkout of github.com/isir/greta (e.g. with the fetch tool, then
#   git --git-dir=MIRROR archive HEAD core/MPEG4 core/Util | tar -x -C GRETA_CHECKOUT)
# OUTDIR: where the compiled classes (Greta's code: never commit them) and greta.toml go.
# Then: fbaconf run --decoder OUTDIR/greta.toml
set -eu
GRETA=$(cd "$1" && pwd)
OUT=$(mkdir -p "$2" && cd "$2" && pwd)
HERE=$(cd "$(dirname "$0")" && pwd)
javac -nowarn -encoding UTF-8 -d "$OUT/classes" -sourcepath "$GRETA/core/Util/src:$GRETA/core/MPEG4/src" \
    "$HERE/GretaFapPlayer.java"
sed "s#@CLASSES@#$OUT/classes#" "$HERE/greta.toml.in" > "$OUT/greta.toml"
echo "wrote $OUT/greta.toml"
