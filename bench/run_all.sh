#!/usr/bin/env bash
# Regenerates every figure in bench/results/ (on this project's 2-core machine: about an hour,
# most of it bench_grid.py's 720 episodes, bench_scenarios.py's 2160 and bench_llm_grid.py's sequential grid).
# One benchmark:  bench/run_all.sh local_model    (the names of bench/results/*.json)
set -euo pipefail
cd "$(dirname "$0")"
declare -A BENCH=(
  [bus]=bench_bus.py [skills]=bench_skills.py [episodes]=bench_episodes.py
  [llm_concurrency]=bench_llm_concurrency.py [prompt_size]=bench_prompt_size.py [eval]=bench_eval.py
  [eval_grid]=bench_grid.py [llm_grid]=bench_llm_grid.py [local_model]=bench_local_model.py [schedulers]=bench_schedulers.py
  [video]=bench_video.py [security]=bench_security.py [memory]=bench_memory.py [ray]=bench_ray.py
  [scenarios]=bench_scenarios.py [teams]=bench_teams.py [env]=bench_env.py [hostile]=bench_hostile.py [rerun]=bench_rerun.py [protocols]=bench_protocols.py [protocol_scaling]=bench_protocol_scaling.py
  [http_client]=bench_http_client.py
)
# Against a baseline tree measured in the same run (issue 46's speed figures): set BASELINE to a
# checkout of the commit to compare with, e.g. `git worktree add /tmp/mhrc-base 1cb6261`
# (bench_env.py takes it too, when set).
declare -A BASELINED=(
  [skill_speed]=bench_skill_speed.py [startup]=bench_startup.py [grid_speed]=bench_grid_speed.py
  [llm_client]=bench_llm_client.py [eval_cpu]=bench_eval_cpu.py
)
declare -A EXTRA=([grid_speed]="--trials 10")  # the paper's 360-episode grid
names=("$@")
[ ${#names[@]} -gt 0 ] || names=(bus skills episodes llm_concurrency prompt_size eval eval_grid llm_grid local_model schedulers video security memory ray scenarios teams env hostile rerun protocols protocol_scaling http_client llm_call_profile skill_speed startup grid_speed llm_client eval_cpu)
for name in "${names[@]}"; do
  if [ "$name" = llm_call_profile ]; then
    script=profile_llm_calls.py
  elif [ -n "${BASELINED[$name]:-}" ]; then
    script=${BASELINED[$name]}
    if [ -z "${BASELINE:-}" ]; then
      echo "== $name skipped: set BASELINE to the tree to compare with" >&2
      continue
    fi
  else
    script=${BENCH[$name]:?"unknown benchmark $name; known: ${!BENCH[*]} ${!BASELINED[*]} llm_call_profile"}
  fi
  args=()
  if [ -n "${BASELINED[$name]:-}" ] || { [ "$name" = env ] && [ -n "${BASELINE:-}" ]; }; then
    args=(--baseline "$BASELINE")
    [ "$name" = env ] && args+=(--rounds 4)  # the trees taking turns: one round is within its noise
  fi
  # shellcheck disable=SC2206
  extra=(${EXTRA[$name]:-})
  echo "== $name ($script)" >&2
  python "$script" "${args[@]}" "${extra[@]}" --out "results/$name.json" > /dev/null
done
python ../docs/hooks/bench.py  # the figures on docs/benchmarks.md, from the JSON just written
