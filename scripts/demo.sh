#!/usr/bin/env bash
# The whole job in a few minutes on 2 cores: render small office, lawn and urban
# sequences, estimate each with ifmi, orb and akaze, evaluate, sweep the iFMI tiling
# on one scene, and write a Markdown + HTML report.
#
#   bash scripts/demo.sh                 # everything under out/demo/
#   OUT=/tmp/demo FRAMES=60 RESOLUTION=384 bash scripts/demo.sh
#   REPORT=reports/demo bash scripts/demo.sh   # the report committed under reports/demo
#
# Reruns reuse finished renders and sweep cells.
set -euo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/setup.sh"

out="${OUT:-out/demo}"
frames="${FRAMES:-30}"
resolution="${RESOLUTION:-256}"
spp="${SPP:-36}"
scenes="${SCENES:-office lawn urban}"
methods="ifmi orb akaze"
report="${REPORT:-$out/report}"

step() { printf '\n== %s\n' "$*"; }
start=$(date +%s)

for scene in $scenes; do
    step "render $scene: $frames frames, ${resolution}x${resolution}, $spp spp"
    omnisim render "scenes/$scene.toml" --out "$out/data/$scene" --frames "$frames" \
        --resolution "$resolution" --spp "$spp"
done

for scene in $scenes; do
    for method in $methods; do
        step "estimate $scene with $method"
        ifmi estimate "$out/data/$scene" --method "$method" --out "$out/estimates/$scene/$method.txt"
        ifmi evaluate --gt "$out/data/$scene/groundtruth.txt" \
            --est "$out/estimates/$scene/$method.txt" --out "$out/eval/$scene/$method"
    done
done

first_scene="${scenes%% *}"
step "sweep tile size x overlap on $first_scene (Dask local cluster)"
ifmi sweep "$out/data/$first_scene" --tile-size 32 64 --overlap 0 0.5 --method ifmi \
    --out "$out/sweep"

step "report"
regenerate="bash scripts/demo.sh"
if [ -n "${REPORT:-}" ]; then regenerate="REPORT=$REPORT $regenerate"; fi
ifmi report "$out/eval" "$out/sweep" --out "$report" --command "$regenerate"

printf '\ndemo finished in %ss\nreport: %s/README.md (Markdown) and %s/index.html (HTML)\n' \
    "$(( $(date +%s) - start ))" "$report" "$report"
