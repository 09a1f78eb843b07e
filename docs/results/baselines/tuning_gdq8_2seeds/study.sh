#!/usr/bin/env bash
# usage: study.sh SAMPLER_SEED N_TRIALS  -- one process of the 2-seed GDQ 8-robot Optuna study (shared SQLite storage).
# Run from the repository root with <study folder> and <checkout> filled in; the 2026-11-30 session (seventh) ran one
# process (sampler seed 201). Before it, two trials were enqueued with optuna's study.enqueue_trial: the package
# defaults (trial 0), and trial 8 of gdq-MultiRobotNav-4-v0-2seeds, the 4-robot tuned entry (trial 1; see
# ../tuning_gdq4_2seeds/). Join with other sampler seeds to go on with the study.
out=<study folder>
mkdir -p $out
cd <checkout> && exec python -m sb3_eps.train \
  --algo gdq --env MultiRobotNav-8-v0 -n 800000 --seed 130 --n-seeds-per-trial 2 -f $out/runs --num-threads 1 \
  --eval-episodes 50 --n-eval-envs 4 --verbose 0 \
  -optimize --n-trials $2 --n-jobs 1 --sampler tpe --pruner median --n-startup-trials 5 --n-evaluations 3 \
  --storage sqlite:///$out/study.db --study-name gdq-MultiRobotNav-8-v0-2seeds --sampler-seed $1 \
  >> $out/process_$1.log 2>&1
