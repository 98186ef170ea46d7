#!/bin/bash
# usage: scratch-run.sh TAG METHOD BONES [ENV=..]...
# Builds CesiumMan with the experiment switches (ENV=VALUE ...) and prints one log line.
# PSK_EXTRA (in the environment of this script) adds build options, e.g. PSK_EXTRA='--rest-frame 0'.
# Run from anywhere after applying a patch and building build-scratch/tools/progskin.
tag=$1; m=$2; nb=$3; shift 3
cd "$(dirname "$0")/../.."
s=$(date +%s.%N)
env "$@" build-scratch/tools/progskin build --from-vertices ../shared/assets/CesiumMan.glb --clip all --fps 30 --bones $nb --method $m $PSK_EXTRA -o /tmp/x_$tag.glb --quiet || exit 1
e=$(date +%s.%N)
build-scratch/tools/progskin inspect /tmp/x_$tag.glb --json > /tmp/x_$tag.json
python3 - /tmp/x_$tag.json "$tag $m $*" "$s" "$e" <<'PY'
import json,sys
sys.argv[2] += ' (%.2fs)' % (float(sys.argv[4]) - float(sys.argv[3]))
r=[x['rms_pct'] for x in json.load(open(sys.argv[1]))['strategies']['scratch']]
g=lambda k: r[min(k,len(r))-1]
mono=all(r[i]<=r[i-1] for i in range(1,len(r)))
print(sys.argv[2], ' '.join('%.3g'%g(k) for k in (2,4,8,16,32)), 'e19=%.3g'%g(19), 'ratios %.2f %.2f %.2f'%(g(4)/1.64,g(8)/0.338,g(16)/0.153), 'mono' if mono else 'RISE')
PY
