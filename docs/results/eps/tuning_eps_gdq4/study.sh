#!/usr/bin/env bash
# usage: study_eps.sh SAMPLER_SEED N_TRIALS  -- one process of the EPS-GDQ 4-robot study (--eps-only, 2 seeds, 100k ticks incl. EPS)
# Before it, the EvolutionCallback defaults and the team world with sharing were enqueued as trials 0 and 1 (optuna's
# study.enqueue_trial with their sample_eps values). Join with other sampler seeds (the session ran 110 then 111 for GDQ, 120 for IQL).
out=<study folder>
mkdir -p $out
cd <checkout> && exec python -m sb3_eps.train \
  --algo eps_gdq --env MultiRobotNav-4-v0 -n 400000 --seed 110 --n-seeds-per-trial 2 -f $out/runs --num-threads 1 \
  --eval-episodes 50 --n-eval-envs 4 --verbose 0 \
  -optimize --eps-only --n-trials $2 --n-jobs 1 --sampler tpe --pruner none --n-startup-trials 5 --n-evaluations 3 \
  --storage sqlite:///$out/study.db --study-name eps_gdq-MultiRobotNav-4-v0-2026-11-30 --sampler-seed $1 \
  >> $out/process_$1.log 2>&1
