#!/bin/sh
# Build fbaconf's Xface adapter OUTSIDE the repository and write its manifest there.
#   examples/third-party/xface/build.sh XFACE_CHECKOUT OUTDIR
# XFACE_CHECKOUT: a checkout of github.com/copperdong/Xface (fetch tool, then git archive);
#   needs g++ and libxerces-c-dev libboost-dev (headers only for the FAP reader).
# OUTDIR: where the binary (Xface's code: never commit it) and xface.toml go.
# Then: fbaconf run --decoder OUTDIR/xface.toml
set -eu
X=$(cd "$1" && pwd)
OUT=$(mkdir -p "$2" && cd "$2" && pwd)
HERE=$(cd "$(dirname "$0")" && pwd)
g++ -O2 -std=gnu++11 -fpermissive -w -include cstring -include cstdio -include cstdlib -include cmath \
    -include string -include algorithm -I "$X/XFace/include" -I "$X/XSmilAgent" \
    -o "$OUT/xface_fap_player" "$HERE/xface_fap_player.cpp" "$X/XFace/src/XFace/FapFile.cpp"
sed "s#@BIN@#$OUT/xface_fap_player#" "$HERE/xface.toml.in" > "$OUT/xface.toml"
echo "wrote $OUT/xface.toml"
