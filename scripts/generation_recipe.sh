# Issue 17's training recipe, sourced by generation_runs.sh and ndms_probe.sh so that both train
# the same model. The caller sets B (the socdiff binary) and O (the output directory).
D=../shared/data
train() { # name seconds args...
  local name=$1 secs=$2; shift 2
  # Width 64, rate 1e-3 and no step limit unless the arguments give others (a cosine schedule
  # ends at the step limit).
  local width=(--hidden 64); [[ " $* " == *" --hidden "* ]] && width=()
  local lr=(--lr 1e-3); [[ " $* " == *" --lr "* ]] && lr=()
  local steps=(--steps 100000000); [[ " $* " == *" --steps "* ]] && steps=()
  # timeout sends SIGINT: training saves its checkpoint and stops.
  timeout -s INT "$secs" "$B" train --out "$O/$name" "${steps[@]}" --batch 16 "${lr[@]}" "${width[@]}" \
    --noise uniform --pose absolute --val-every 0 --save-every 200 --seed 0 "$@" > "$O/$name.log" 2>&1
}
bandai=(--data $D/bandai2 --window 96 --observed 30 --stride 5 --persons-min 1 --persons-max 1 --body-scale 0)
mupots=(--data $D/mupots3d --window 120 --observed 30 --stride 5 --body-scale 0.1 --limb-scale 0.05)
# The L2 lookahead bandai2 recipe of docs/recipes.md §9 (x0, Wiener input scaling σ_d 1, take
# balance, lookahead, squared error), as one word list; each probe adds its --velocity-loss.
bandai_l2="--input-scaling wiener --sigma-data 1 --balance sequences --causality lookahead --loss l2"
# What every bandai2 generation probe scores, against the split given beside it:
# `"$B" eval --split test --generated … "${bandai_scores[@]}" --out …`.
bandai_scores=(--reference $D/bandai2 --kinds-data $D/bandai2 --metrics ndms,apd,bone-length,speed,acceleration,jerk,coverage,kinds)
