#!/usr/bin/env bash
# make_figures.sh — regenerates the README figures of the default character.
#
#   scripts/make_figures.sh [--build DIR] [--demo | --rd TABLE]
#
#   docs/figures/fox_lods.png          Fox, clip Survey, t = 1.7 s, 1, 2, 4 bones and the full rig
#   docs/figures/fox_lods_heatmap.png  the same, vertices coloured by their error
#   docs/figures/fox_error.svg         error against bones per strategy (progskin inspect --plot)
#   docs/figures/rate_distortion.svg   with --demo (runs scripts/demo.sh) or --rd TABLE (its saved
#                                      output, or CSV: see scripts/plot_rd.sh)
#
# Needs the render/ packages (libegl-dev libgl-dev libegl-mesa0 libgl1-mesa-dri libstb-dev) and
# gnuplot-nox; builds the progskin target into DIR (default: build, or $PROGSKIN_BUILD) if missing.
# Rendering runs on Mesa's llvmpipe when there is no GPU: images are the same on any machine
# up to rasteriser rounding.
set -euo pipefail
cd "$(dirname "$0")/.."
BUILD=${PROGSKIN_BUILD:-build}
RD=""
DEMO=0
while (($#)); do
  case "$1" in
    --build) BUILD=$2; shift 2;;
    --demo) DEMO=1; shift;;
    --rd) RD=$2; shift 2;;
    -h|--help) sed -n '2,17p' "$0" | sed 's/^# \{0,1\}//'; exit 0;;
    *) echo "make_figures: unknown argument $1" >&2; exit 2;;
  esac
done
PROGSKIN=$BUILD/tools/progskin
if [[ ! -x $PROGSKIN ]] || ! "$PROGSKIN" --help | grep -q 'progskin render'; then
  echo "make_figures: building progskin into $BUILD ..." >&2
  cmake -S . -B "$BUILD" >/dev/null
  cmake --build "$BUILD" -j"$(nproc)" --target progskin >/dev/null
fi
"$PROGSKIN" --help | grep -q 'progskin render' ||
  { echo "make_figures: $PROGSKIN was built without render/ (see the cmake message)" >&2; exit 1; }
mkdir -p docs/figures

FOX=assets/Fox.glb
TMP=$(mktemp -d)
trap 'rm -rf "$TMP"' EXIT
# A plain glTF: render builds its progressive skin (reorder, 30 fps), as `progskin build` would.
"$PROGSKIN" render "$FOX" --clip Survey --time 1.7 --bones 1,2,4,all \
  -o docs/figures/fox_lods.png --quiet
"$PROGSKIN" render "$FOX" --clip Survey --time 1.7 --bones 1,2,4,all --heatmap \
  -o docs/figures/fox_lods_heatmap.png --quiet
"$PROGSKIN" inspect "$FOX" --quiet --plot docs/figures/fox_error.svg >/dev/null
echo "make_figures: wrote docs/figures/fox_lods.png, fox_lods_heatmap.png, fox_error.svg" >&2

if ((DEMO)); then
  scripts/demo.sh --build "$BUILD" | tee "$TMP/demo.txt"
  RD=$TMP/demo.txt
fi
if [[ -n $RD ]]; then
  scripts/plot_rd.sh --title "Fox + CesiumMan streaming: displayed error against measured rate" \
    "$RD" docs/figures/rate_distortion.svg
fi
