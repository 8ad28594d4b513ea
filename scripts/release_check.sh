#!/usr/bin/env bash
# Release check: a newcomer's first hour on a fresh venv, end to end.
#   bash scripts/release_check.sh            (about 5 minutes on 2 cores)
# 1. the README's main-job install, with the quick leaderboard;
# 2. the README's test install, editable, over it in the same venv;
# 3. `stepdamp presets` from another directory;
# 4. a tiny agent trained and put on the leaderboard by its file;
# 5. uninstall: no stepdamp_env folder may remain in site-packages.
set -euo pipefail
repo="$(cd "$(dirname "$0")/.." && pwd)"
work="$(mktemp -d)"
trap 'rm -rf "$work"' EXIT
export MPLBACKEND=Agg XDG_CACHE_HOME="$work/cache"   # numba cache: a per-user directory
unset NUMBA_CACHE_DIR
python3 -m venv "$work/venv"
. "$work/venv/bin/activate"
step() { printf '\n== %s\n' "$*"; }
cd "$repo"

step "1. main job (README), quick variant"
python -m pip install -q -c constraints.txt . 2>&1 | grep -v "^WARNING: Location" || true
t0=$(date +%s)
stepdamp leaderboard --quick --no-progress --out "$work/lb" | tail -n 12
echo "quick leaderboard: $(( $(date +%s) - t0 )) s"

step "2. test install (README), editable, same venv"
python -m pip install -q -c constraints.txt -e ".[test]" 2>&1 | grep -v "^WARNING: Location" || true
python -c "import stepdamp_env, stepdamp_baselines, stepdamp_agents; print('imports from', stepdamp_env.__file__)"

step "3. stepdamp presets from another directory"
(cd "$work" && stepdamp presets)

step "4. a tiny agent, trained and put on the leaderboard"
(cd "$work" && stepdamp train --algo ppo --total-timesteps 128 --eval-freq 0 \
    --checkpoint-freq 0 --no-progress --no-tensorboard --out run | tail -n 2)
(cd "$work" && stepdamp leaderboard --quick --no-progress --no-plots --suite open-loop \
    --entries none ff-delay-comp --policy run/final.zip --out lb-agent | tail -n 5)

step "5. uninstall leaves nothing in site-packages"
site="$(python -c 'import sysconfig; print(sysconfig.get_paths()["purelib"])')"
python -m pip uninstall -q -y stepdamp-env
left="$(ls -d "$site"/stepdamp* 2>/dev/null || true)"
if [ -n "$left" ]; then echo "LEFT BEHIND: $left"; exit 1; fi
echo "site-packages holds no stepdamp_env, stepdamp_baselines or stepdamp_agents"
echo
echo "release check passed"
