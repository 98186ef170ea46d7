#!/usr/bin/env bash
# plot_rd.sh — the streaming rate-distortion table as a plot (gnuplot).
#
#   scripts/plot_rd.sh [--title T] INPUT OUT.svg|.png|.pdf
#   scripts/demo.sh | scripts/plot_rd.sh - docs/figures/rate_distortion.svg
#
# INPUT ("-" = stdin) is either
#  * the text table scripts/demo.sh prints (detected by its "cap kbit/s"
#    header): every row becomes a point of the series "progressive"; or
#  * CSV with a header row naming its columns, in any order:
#      method,cap_kbps,rate_kbps,bones_mean,rms_pct,max_pct
#    rate_kbps and rms_pct are required; method (one series per distinct
#    value: progressive streaming and each baseline, e.g. "all bones",
#    "fixed k=4"), max_pct, bones_mean and cap_kbps are optional. Lines
#    starting with # are ignored.
# Rate is what the client measured (UDP payload + 28 bytes per datagram, in
# kbit/s); errors are % of the rest bounding-box diagonal (docs/metrics.md §2).
# Left panel: RMS error against rate; right panel: max error (when present).
set -euo pipefail
TITLE="rate-distortion: displayed error against measured rate"
while (($#)); do
  case "$1" in
    --title) TITLE=$2; shift 2;;
    -h|--help) sed -n '2,20p' "$0" | sed 's/^# \{0,1\}//'; exit 0;;
    *) break;;
  esac
done
if (($# != 2)); then sed -n '2,20p' "$0" | sed 's/^# \{0,1\}//' >&2; exit 2; fi
IN=$1 OUT=$2
command -v gnuplot >/dev/null || { echo "plot_rd: gnuplot not found (Debian: apt-get install gnuplot-nox)" >&2; exit 1; }
TMP=$(mktemp -d)
trap 'rm -rf "$TMP"' EXIT
if [[ $IN == - ]]; then cat >"$TMP/in"; else cp "$IN" "$TMP/in"; fi

# Normalise to "method<TAB>rate<TAB>rms<TAB>max<TAB>bones", one line per point.
if grep -q 'cap kbit/s' "$TMP/in"; then
  awk -v OFS='\t' '
    /cap kbit\/s/ { table = 1; next }
    table && NF >= 6 && ($1 ~ /^[0-9.]+$/ || $1 == "unlimited") && $2 ~ /^[0-9.]+$/ {
      print "progressive", $2, $5, $6, $4 }' "$TMP/in" >"$TMP/points"
else
  awk -F',' -v OFS='\t' '
    /^[[:space:]]*#/ || NF == 0 { next }
    !header { for (i = 1; i <= NF; ++i) { gsub(/^[ \t"]+|[ \t"]+$/, "", $i); col[$i] = i }; header = 1
              if (!("rate_kbps" in col) || !("rms_pct" in col)) { print "plot_rd: CSV needs rate_kbps and rms_pct columns" > "/dev/stderr"; exit 3 }
              next }
    { for (i = 1; i <= NF; ++i) gsub(/^[ \t"]+|[ \t"]+$/, "", $i)
      m = ("method" in col) ? $col["method"] : "progressive"
      print m, $col["rate_kbps"], $col["rms_pct"], ("max_pct" in col) ? $col["max_pct"] : "NaN",
            ("bones_mean" in col) ? $col["bones_mean"] : "NaN" }' "$TMP/in" >"$TMP/points"
fi
[[ -s $TMP/points ]] || { echo "plot_rd: no data rows in $IN" >&2; exit 1; }

# One gnuplot data block per method (sorted by rate), in order of first appearance.
awk -F'\t' '!seen[$1]++ { print $1 }' "$TMP/points" >"$TMP/methods"
: >"$TMP/data"
while IFS= read -r m; do
  echo "# $m" >>"$TMP/data"
  awk -F'\t' -v m="$m" -v OFS=' ' '$1 == m { print $2, $3, $4, $5 }' "$TMP/points" | sort -g >>"$TMP/data"
  printf '\n\n' >>"$TMP/data"
done <"$TMP/methods"
HAS_MAX=$(awk -F'\t' '$4 != "NaN" { n++ } END { print n + 0 }' "$TMP/points")

case "${OUT##*.}" in
  png|PNG) TERM_LINE="set terminal pngcairo size 1000,440 font 'sans,11'";;
  pdf|PDF) TERM_LINE="set terminal pdfcairo size 10.4in,4.6in font 'sans,10'";;
  *) TERM_LINE="set terminal svg size 1000,440 dynamic font 'sans,12' background '#ffffff'";;
esac
q() { printf "'%s'" "${1//\'/\'\'}"; }
{
  echo "$TERM_LINE"
  echo "set output $(q "$OUT")"
  if ((HAS_MAX)); then echo "set multiplot layout 1,2 title $(q "$TITLE") noenhanced"; else echo "set title $(q "$TITLE") noenhanced"; fi
  echo "set xlabel 'measured rate, kbit/s per client'"
  echo "set grid lc rgb '#dddddd'"
  echo "set key top right noenhanced"
  echo "set yrange [0:*]"
  echo "set style data linespoints"
  for panel in rms max; do
    [[ $panel == max ]] && ((HAS_MAX == 0)) && break
    if [[ $panel == rms ]]; then echo "set ylabel 'RMS error, % of rest bounding-box diagonal'"; c=2
    else echo "set ylabel 'max error, % of rest bounding-box diagonal'"; echo "unset key"; c=3; fi
    i=0; n=$(wc -l <"$TMP/methods"); sep="plot"
    while IFS= read -r m; do
      echo "$sep $(q "$TMP/data") index $i using 1:$c lw 2 pt 7 ps 0.6 lc $((i + 1)) title $(q "$m") \\"
      sep=","; i=$((i + 1))
    done <"$TMP/methods"
    echo ""
  done
  ((HAS_MAX)) && echo "unset multiplot"
} >"$TMP/plot.gp"
gnuplot "$TMP/plot.gp"
echo "plot_rd: wrote $OUT ($(wc -l <"$TMP/methods") series, $(wc -l <"$TMP/points") points)" >&2
