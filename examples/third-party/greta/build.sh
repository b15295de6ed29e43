#!/bin/sh
# Build fbaconf's Greta adapters OUTSIDE the repository and write their manifests there.
#   examples/third-party/greta/build.sh GRETA_CHECKOUT OUTDIR
# GRETA_CHECKOUT: a checkout of github.com/isir/greta (e.g. with the fetch tool, then
#   git --git-dir=MIRROR archive HEAD core/MPEG4 core/Util | tar -x -C GRETA_CHECKOUT)
# OUTDIR: where the compiled classes (Greta's code: never commit them) and the manifests go:
#   greta.toml         Greta as a player (GretaFapPlayer: FAPParser + APFrameList, what MPEG4Animatable does)
#   greta-parser.toml  Greta's parser alone (GretaFapParser: each frame's own mask, no player state)
# Then: fbaconf run --decoder OUTDIR/greta.toml --sandbox-ro /usr/lib/jvm   (the JVM the sandbox shows)
set -eu
GRETA=$(cd "$1" && pwd)
OUT=$(mkdir -p "$2" && cd "$2" && pwd)
HERE=$(cd "$(dirname "$0")" && pwd)
javac -nowarn -encoding UTF-8 -d "$OUT/classes" -sourcepath "$GRETA/core/Util/src:$GRETA/core/MPEG4/src" \
    "$HERE/GretaFapPlayer.java" "$HERE/GretaFapParser.java"
sed -e "s#@CLASSES@#$OUT/classes#g" -e "s#@CLASS@#GretaFapPlayer#g" -e "s#@NAME@#greta-player#" \
    -e "s#@WHAT@#Greta's player state (APFrameList)#g" "$HERE/greta.toml.in" > "$OUT/greta.toml"
sed -e "s#@CLASSES@#$OUT/classes#g" -e "s#@CLASS@#GretaFapParser#g" -e "s#@NAME@#greta-fap-parser#" \
    -e "s#@WHAT@#the parser's frames alone, not a player's state#g" "$HERE/greta.toml.in" > "$OUT/greta-parser.toml"
echo "wrote $OUT/greta.toml $OUT/greta-parser.toml"
