#!/bin/bash
# Does prediction help a learned planner? Four PPO trainings side by side on HighwayDense-v0 (bench/train_ppo.py,
# same seed, --n-envs 4, the same wall-clock budget TRAIN_S each): no forecast observation (default reward), no
# forecast with the ttc reward weight 0, const-vel and TraPHic forecast observations; each keeps a checkpoint
# every 20,480 steps. Then bench/score_ppo.py scores them on held-out highway_mixed_dense seeds beside the
# prediction-driven planner on const-vel forecasts, with paired differences at equal training steps (the largest
# checkpoint the slower forecast variant reached). Needs about 20 cores to run the four side by side.
#
# Usage: TRAIN_S=300 SEEDS=100-115 WORKERS=16 OUT=runs/ppo_forecast bash bench/ppo_forecast.sh
set -u
PY=${PY:-python}
T=${TRAIN_S:-300}; STEPS=${STEPS:-2000000}; SEEDS=${SEEDS:-100-115}; W=${WORKERS:-16}; SC=${SCORE_S:-100000}
DUR=${DUR:+--duration $DUR}
export OMP_NUM_THREADS=1 MKL_NUM_THREADS=1 PYTHONUNBUFFERED=1 MPLBACKEND=Agg
OUT=${OUT:-runs/ppo_forecast}; R=$OUT/r; K=$OUT/w; rm -rf "$K"; mkdir -p "$R" "$K"
for v in none nottc const-vel traphic; do
  extra=""; [ $v = nottc ] && extra="--reward ttc=0"
  [ $v = const-vel ] || [ $v = traphic ] && extra="--predictor $v"
  $PY bench/train_ppo.py --steps "$STEPS" --deadline "+$T" --seed 0 --n-envs 4 $extra --keep-checkpoints \
     --save-every "${SAVE:-20480}" --run "$K/run_$v" --policy "$K/ppo_$v.zip" --figure "$R/curve_$v.png" \
     > "$R/train_$v.log" 2>&1 &
done
wait
for v in none nottc const-vel traphic; do cp "$K/run_$v/curve.json" "$R/curve_$v.json"; cp "$K/ppo_$v.json" "$R/"; done
$PY bench/train_ppo.py --plot "$R/curves.png" "no forecast=$R/curve_none.json" \
  "no forecast, ttc weight 0=$R/curve_nottc.json" "const-vel forecasts=$R/curve_const-vel.json" \
  "TraPHic forecasts=$R/curve_traphic.json"
last() { ls "$K/run_$1/checkpoints/" | sed 's/.zip//' | sort -n | tail -1; }
STR=$(last traphic); SCV=$(last const-vel); echo "traphic $STR const-vel $SCV" > "$R/equal_steps.txt"
for v in none const-vel traphic; do for s in $STR $SCV; do
  [ -f "$K/run_$v/checkpoints/$s.zip" ] && cp "$K/run_$v/checkpoints/$s.zip" "$K/${v}_$s.zip" \
    && cp "$K/ppo_$v.json" "$K/${v}_$s.json"
done; done
E="const-vel"; P=""
add() { [ -f "$2" ] && E="$E,$1=$2"; return 0; }
pair() { case ",$E," in *",$1="*) case ",$E," in *",$2="*) P="$P,$1:$2";; esac;; esac; return 0; }
add ppo "$K/ppo_none.zip"; add nottc "$K/ppo_nottc.zip"
add "none_$SCV" "$K/none_$SCV.zip"; add "cv_$SCV" "$K/const-vel_$SCV.zip"
add "none_$STR" "$K/none_$STR.zip"; add "cv_$STR" "$K/const-vel_$STR.zip"; add "traphic_$STR" "$K/traphic_$STR.zip"
pair nottc ppo; pair "cv_$SCV" "none_$SCV"; pair "cv_$STR" "none_$STR"; pair "traphic_$STR" "none_$STR"
timeout "$SC" $PY bench/score_ppo.py --seeds "$SEEDS" --workers "$W" --out "$R/score_hw" $DUR --egos "$E" \
  --pairs "$P" > "$R/score_hw.log" 2>&1
tail -n 20 "$R/score_hw.log"
