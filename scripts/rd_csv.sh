#!/usr/bin/env bash
# rd_csv.sh — turns the rate-distortion table that build/bench/bench_net_rd
# prints into the CSV scripts/plot_rd.sh reads, for one scene.
#
#   build/bench/bench_net_rd | scripts/rd_csv.sh [SCENE] > rd.csv      (SCENE: default | crowd)
set -euo pipefail
case "${1:-}" in -h|--help) sed -n '2,6p' "$0" | sed 's/^# \{0,1\}//'; exit 0;; esac
scene=${1:-default}
echo "method,cap_kbps,rate_kbps,bones_mean,rms_pct,max_pct"
awk -F'|' -v scene="$scene" '
  function trim(s) { gsub(/^ +| +$/, "", s); return s }
  index(trim($2), scene) == 1 && trim($4) != "" && trim($4) !~ /best baseline/ {
    m = trim($4); gsub(/, /, " / ", m); gsub(/,/, " ", m)
    printf "%s,%s,%s,%s,%s,%s\n", m, trim($3), trim($5), trim($6), trim($7), trim($8)
  }'
