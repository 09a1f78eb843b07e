#!/usr/bin/env bash
# usage: study.sh SAMPLER_SEED N_TRIALS  -- one process of the GDQ 4-robot Optuna study (shared SQLite storage);
# the 2026-11-30 session ran two (sampler seeds 100 and 101, 7 trials each) and enqueued the package defaults once.
out=<study folder>
mkdir -p $out
cd <checkout> && exec python -m sb3_eps.train \
  --algo gdq --env MultiRobotNav-4-v0 -n 600000 --seed 100 -f $out/runs --num-threads 1 \
  --eval-episodes 50 --n-eval-envs 4 --verbose 0 \
  -optimize --n-trials $2 --n-jobs 1 --sampler tpe --pruner median --n-startup-trials 5 --n-evaluations 3 \
  --storage sqlite:///$out/study.db --study-name gdq-MultiRobotNav-4-v0-2026-11-30 --sampler-seed $1 \
  >> $out/process_$1.log 2>&1
