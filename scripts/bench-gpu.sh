#!/bin/sh
# The speed measurements that need a real GPU, in one run (a lent GPU machine's time is short):
# the speed/accuracy fronts of the avs paper scenes at the papers' 640x480 against converged
# references, the ray tracer against obvhs on the same machine, and `bench avs` (Table 1 columns,
# avs against mc) at 640x480. Every step has its own time limit and leaves its output as a
# tarball, so a step cut short costs only itself.
#
#   scripts/bench-gpu.sh BIN OUT REFERENCE_CACHE [NOISE]
#
# BIN: a release build of `penumbra`; OUT: output folder; REFERENCE_CACHE: converged 640x480
# references of falling, hat_on_cloth and balls_on_dish (`bench matrix --scenes ... --techniques
# env --size 640x480 --noise NOISE --cache DIR` renders them on the CPU, anti-aliased (its default
# --supersample 2, hence --reference-grid 2 below): about 11 min per scene at NOISE 0.01 on two
# cores). The references are looked up, not rendered: `--max-spp 256` bounds the damage when one is
# missing (the log then says "256 spp"). Session 19 ran these steps on an NVIDIA H200 (README,
# "The trade on a GPU") with the references kept in scenes/fronts/h200/references/ (NOISE 0.01):
#   scripts/bench-gpu.sh target/release/penumbra OUT scenes/fronts/h200/references 0.01
set -u
BIN=$1
OUT=$2
REFS=$3
NOISE=${4:-0.01}
mkdir -p "$OUT"
log="$OUT/bench-gpu.log"
. "$(dirname "$0")/bench-steps.sh"
fast=env,mc,shadowmaps,isg,isg-vertex,shadow-fields,shadow-fields-fixed,shadow-fields-wavelet
for scene in falling hat_on_cloth balls_on_dish; do
    # avs apart: its CPU rounds grow with the resolution, and a cut step loses only its own points
    # (`bench pareto --from` redraws the merged points)
    for group in fast avs; do
        if [ "$group" = fast ]; then t=$fast; limit=70; else t=avs; limit=60; fi
        step "pareto_${scene}_$group" $limit "$BIN" bench pareto "scenes/$scene.toml" --techniques "$t" --size 640x480 --reference-grid 2 \
            --noise "$NOISE" --max-spp 256 --cache "$REFS" --out "$OUT/pareto_${scene}_$group"
        (cd "$OUT" && tar czf "pareto_${scene}_$group.tgz" "pareto_${scene}_$group" "pareto_${scene}_$group.txt" 2>/dev/null &&
            rm -rf "pareto_${scene}_$group" "pareto_${scene}_$group.txt")
    done
done
for scene in falling hat_on_cloth; do
    step "trace_$scene" 20 "$BIN" bench trace "scenes/$scene.toml" --size 640x480 --incoherent 1000000
done
step avs 80 "$BIN" bench avs --size 640x480 --no-sweep --spp 64
(cd "$OUT" && tar czf rest.tgz ./*.txt 2>/dev/null && rm -f ./*.txt)
