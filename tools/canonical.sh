#!/usr/bin/env bash
# Regenerates the canonical results, benchmarks/results/<benchmark>-h200.{json,md,png}, on the H200 machine: each
# entry point's canonical run (the command its --help begins with), then the README's results table from
# frame-h200.json.
#
#   tools/canonical.sh [all | part1 | part2 | part3 | readme | ENTRY ...]
#
#   part1   frame, reorder, then readme (estimated 8 minutes of H200 time: one call of under 10 minutes)
#   part2   stages, dof, indirect, viewer, robustness, cpu (estimated 7 minutes)
#   part3   textured (frame-textured: the textured scenes, over 10 minutes: on a 10-minute call, a few scenes at
#           a time with --keep), textures (stages-textures: their G-buffer and shading with and without textures,
#           2.5 minutes) (estimated 14 minutes)
#   part4   path (path: foveated against full-resolution path tracing on cornell, bunny, city at 1920x1080, then
#           path4k: at 3840x2160, FovVideoVDP on cornell and bunny against 64-path whole-frame targets, one scene
#           per run; pathrooms: the textured room and the Grey & White Room at 1920x1080,
#           pathrooms4k: the room at 3840x2160, pathgwr4k: the Grey & White Room at 3840x2160, all kept in the
#           same JSON), pathvariants (path-variants: the foveated reconstruction with and without demodulation and
#           filter) (estimated 8 x 6 minutes)
#   all     part1 to part4 (the default)
#   readme  only the README's results table, from benchmarks/results/frame-h200.json
#   ENTRY   one or more entry point names (frame, reorder, stages, dof, indirect, viewer, robustness, cpu,
#           textured, textures, path, path4k, pathrooms, pathrooms4k, pathgwr4k, pathvariants)
#
# The GPU machine has a copy of the working tree without .git: set FOVEAWARP_COMMIT to the commit it came from
# (every JSON records it). Meshes that assets/ does not ship (nefertiti) are read from $FOVEAWARP_SCENES or a
# shared/scenes folder in or beside the checkout; a missing one is skipped and named on stderr. cpu runs on the
# host CPU of the H200 machine (--device cpu). The time estimates come from the sizes below; each JSON's wall_s
# records what a run took. Exit status 1 when any run failed (the others still run).
set -uo pipefail
cd "$(dirname "$0")/.."

if [ -z "${FOVEAWARP_COMMIT:-}" ]; then
    if FOVEAWARP_COMMIT=$(git rev-parse HEAD 2>/dev/null); then
        export FOVEAWARP_COMMIT
    else
        echo "canonical.sh: no .git and FOVEAWARP_COMMIT unset: the results will say commit 'unknown'" >&2
        unset FOVEAWARP_COMMIT
    fi
fi
export PYTHONUNBUFFERED=1
mkdir -p benchmarks/results benchmarks/out
failed=()

run() {  # run NAME COMMAND...: the command, its time and its exit status
    local name=$1 t0=$SECONDS
    shift
    echo "== $name: $*" >&2
    if "$@"; then
        echo "== $name: done in $((SECONDS - t0)) s" >&2
    else
        echo "== $name: FAILED (exit $?) after $((SECONDS - t0)) s" >&2
        failed+=("$name")
    fi
}

canonical_frame() {
    run frame python benchmarks/frame.py --device cuda:0 --out benchmarks/results --tag h200 \
        --scenes cornell,bunny --sizes 1920x1080,3840x2160 --ao-samples 0,8 --frames 20 --timing-frames 20
}
canonical_textured() {
    run textured python benchmarks/frame.py --device cuda:0 --out benchmarks/results --tag textured-h200 \
        --scenes room,suzanne,wicker,barrel,milk-truck --sizes 1920x1080,3840x2160 --ao-samples 0 \
        --frames 20 --timing-frames 20
}
canonical_textures() {
    run textures python benchmarks/stages.py --device cuda:0 --out benchmarks/results --tag textures-h200 \
        --parts textures --sizes 1920x1080,3840x2160
}
canonical_path() {
    run path python benchmarks/path.py --device cuda:0 --out benchmarks/results --tag h200 \
        --scenes cornell,bunny,city --sizes 1920x1080 --images benchmarks/out/path-images
}
canonical_path4k() {  # cornell and bunny with a whole-frame target for FovVideoVDP (6 minutes each), city without
    local s
    for s in cornell bunny city; do
        local keep=() whole=()
        [ -f benchmarks/results/path-h200.json ] && keep=(--keep benchmarks/results/path-h200.json)
        [ "$s" != city ] && whole=(--whole-max-pixels 8294400 --converged-spp 64)
        run "path4k $s" python benchmarks/path.py --device cuda:0 --out benchmarks/results --tag h200 \
            --scenes "$s" --sizes 3840x2160 --images benchmarks/out/path-images "${whole[@]}" "${keep[@]}"
    done
}
canonical_pathrooms() {
    local keep=()
    [ -f benchmarks/results/path-h200.json ] && keep=(--keep benchmarks/results/path-h200.json)
    run pathrooms python benchmarks/path.py --device cuda:0 --out benchmarks/results --tag h200 \
        --scenes room,grey-white-room --sizes 1920x1080 --converged-spp 48 --warm 4 \
        --images benchmarks/out/path-images "${keep[@]}"
}
canonical_pathrooms4k() {
    local keep=()
    [ -f benchmarks/results/path-h200.json ] && keep=(--keep benchmarks/results/path-h200.json)
    run pathrooms4k python benchmarks/path.py --device cuda:0 --out benchmarks/results --tag h200 \
        --scenes room --sizes 3840x2160 --converged-spp 48 --warm 4 "${keep[@]}"
}
canonical_pathgwr4k() {  # fovea metrics only, as the room at 4K; the scene is read from $FOVEAWARP_SCENES_DIR
    local keep=()
    [ -f benchmarks/results/path-h200.json ] && keep=(--keep benchmarks/results/path-h200.json)
    run pathgwr4k python benchmarks/path.py --device cuda:0 --out benchmarks/results --tag h200 \
        --scenes grey-white-room --sizes 3840x2160 --converged-spp 48 --warm 4 "${keep[@]}"
}
canonical_pathvariants() {
    run pathvariants python benchmarks/path.py --device cuda:0 --out benchmarks/results --tag variants-h200 \
        --scenes cornell,room --sizes 1920x1080 --full-spp 1,2,4 --fov-spp 1,2,4 --budgets pixel \
        --variants plain,demod,filter,demod+filter --converged-spp 48 --warm 4 --fovea-spp 512
}
canonical_reorder() {
    run reorder python benchmarks/reorder.py --device cuda:0 --out benchmarks/results --tag h200 \
        --scenes cornell,city,bunny --sizes 1920x1080,3840x2160
}
canonical_stages() {
    run stages python benchmarks/stages.py --device cuda:0 --out benchmarks/results --tag h200 \
        --parts sampling,reconstruct,bvh,metrics,reference \
        --sizes 1920x1080,3840x2160 --scenes cornell,city,bunny,nefertiti
}
canonical_dof() {
    run dof python benchmarks/dof.py --device cuda:0 --out benchmarks/results --tag h200
}
canonical_indirect() {
    run indirect python benchmarks/indirect.py --device cuda:0 --out benchmarks/results --tag h200 \
        --scenes cornell,bunny-in-box --rsm 256
}
canonical_viewer() {
    run viewer python benchmarks/viewer.py --device cuda:0 --out benchmarks/results --tag h200
}
canonical_robustness() {
    # parity: the CPU half saves its arrays on this machine's host, the CUDA run compares against them (without
    # them, as when this Warp build has no CPU compiler, the CUDA run checks its own determinism only)
    rm -f benchmarks/out/parity-cpu.npz
    run robustness-cpu python benchmarks/robustness.py --parts parity --device cpu \
        --save benchmarks/out/parity-cpu.npz --out benchmarks/out
    if [ -f benchmarks/out/parity-cpu.npz ]; then
        run robustness python benchmarks/robustness.py --device cuda:0 --out benchmarks/results --tag h200 \
            --compare benchmarks/out/parity-cpu.npz
    else
        run robustness python benchmarks/robustness.py --device cuda:0 --out benchmarks/results --tag h200
    fi
}
canonical_cpu() {
    run cpu python benchmarks/cpu.py --device cpu --out benchmarks/results --tag h200
}
canonical_readme() {
    if [ -f benchmarks/results/frame-h200.json ]; then
        run readme python benchmarks/frame.py --summarize benchmarks/results/frame-h200.json --readme README.md
    else
        echo "== readme: benchmarks/results/frame-h200.json is missing: README left as it is" >&2
        failed+=(readme)
    fi
}

PART1=(frame reorder readme)
PART2=(stages dof indirect viewer robustness cpu)
PART3=(textured textures)
PART4=(path path4k pathrooms pathrooms4k pathgwr4k pathvariants)
ENTRIES=(frame reorder stages dof indirect viewer robustness cpu textured textures path path4k pathrooms pathrooms4k
         pathgwr4k pathvariants readme)

todo=()
[ $# -eq 0 ] && set -- all
if [ "$1" = "-h" ] || [ "$1" = "--help" ]; then
    sed -n '2,/^set -uo/p' "$0" | sed -e '$d' -e 's/^# \{0,1\}//'
    exit 0
fi
for arg in "$@"; do
    case "$arg" in
        all) todo+=("${PART1[@]}" "${PART2[@]}" "${PART3[@]}" "${PART4[@]}") ;;
        part1) todo+=("${PART1[@]}") ;;
        part2) todo+=("${PART2[@]}") ;;
        part3) todo+=("${PART3[@]}") ;;
        part4) todo+=("${PART4[@]}") ;;
        *)
            if [[ " ${ENTRIES[*]} " == *" $arg "* ]]; then
                todo+=("$arg")
            else
                echo "canonical.sh: unknown part or entry point '$arg' (allowed: all, part1, part2, part3, part4, ${ENTRIES[*]})" >&2
                exit 2
            fi ;;
    esac
done

for name in "${todo[@]}"; do
    "canonical_$name"
done
if [ ${#failed[@]} -gt 0 ]; then
    echo "canonical.sh: failed: ${failed[*]}" >&2
    exit 1
fi
echo "canonical.sh: all done: ${todo[*]}" >&2
