#!/usr/bin/env bash
# The SLURM launcher (hydra/launcher=slurm, issue #24) against a real one-node
# SLURM started on localhost by scripts/slurm_local.sh (munged, slurmctld,
# slurmd; needs root and the Debian packages slurm-wlm and munge):
#   1. a 4-job demo sweep with wait=true, one job failing: the others finish,
#      the ledger says done/done/failed/done, every job dir has .hydra/, its
#      log, SLURM's stdout/stderr and the wrapper's exit status, provenance
#      names the SLURM array task and node, the failure is listed with its log;
#   2. the same command again submits only the failed job;
#   3. bad input: sbatch missing, the controller unreachable, a partition
#      SLURM rejects: one line, exit 1, the ledger unchanged;
#   4. wait=false returns at once printing the sweep dir; `soma sweep status`
#      shows running/pending jobs; `soma sweep cancel` scancels them and they
#      are failed in the ledger;
#   5. wait=true interrupted with SIGINT cancels its array;
#   6. preemption: a checkpointing job signalled with `scancel --signal=USR1
#      -b` is requeued, resumes from its checkpoint and ends with the metrics
#      of an uninterrupted run.
#   slurm_test.sh <soma executable> <source dir>
# Exit 77 (CTest: skipped) when not root or SLURM/munge are not installed.
set -euo pipefail
soma=$(realpath "$1")
source=$(realpath "$2")
PATH=$PATH:/usr/sbin

if [[ $(id -u) -ne 0 ]]; then
  echo "slurm_test: SKIP: needs root to run slurmd" >&2
  exit 77
fi
for tool in munged slurmctld slurmd sbatch squeue scancel sinfo; do
  if ! command -v "$tool" >/dev/null 2>&1; then
    echo "slurm_test: SKIP: '$tool' not installed (scripts/install_deps.sh" \
         "installs slurm-wlm and munge)" >&2
    exit 77
  fi
done

work=$(mktemp -d /tmp/soma_slurm_test.XXXXXX)
cluster=$work/cluster
cleanup() {
  bash "$source/scripts/slurm_local.sh" stop "$cluster" || true
  rm -rf "$work"
}
trap cleanup EXIT
fail() {
  echo "slurm_test: FAIL: $*" >&2
  for f in "$cluster"/log/slurmctld.log "$cluster"/log/slurmd.log; do
    [[ -f $f ]] && { echo "--- tail $f" >&2; tail -5 "$f" >&2; }
  done
  exit 1
}
step() { echo "slurm_test: [$(( SECONDS ))s] $*"; }

SECONDS=0
eval "$(bash "$source/scripts/slurm_local.sh" start "$cluster")"
export SLURM_CONF
step "cluster up: $(sinfo -h -o '%P %t %c cpus %m MB' | head -1)"

mkdir "$work/run"
cd "$work/run"
# Cheap demo jobs (configs/task/demo.yaml); job 2 fails at step 1.
sweep_args=(-cn demo -m task.steps=5 'task.fail_at_step=-1,-2,1,-3'
            hydra/launcher=slurm hydra.launcher.poll_interval_s=0.5
            hydra.sweep.dir="$work/run/sweep")
sweep=$work/run/sweep
csv_status() { cut -d, -f1-3 "$sweep/jobs.csv" | tail -n +2 | tr '\n' ' '; }

# --- 1. wait=true, one failing job -------------------------------------------
set +e
"$soma" "${sweep_args[@]}" >out1.txt 2>&1
rc=$?
set -e
[[ $rc -eq 1 ]] || { cat out1.txt; fail "sweep with a failing job exited $rc, not 1"; }
[[ $(csv_status) == "0,done,1 1,done,1 2,failed,1 3,done,1 " ]] ||
  fail "ledger after the first run: $(csv_status)"
grep -q "Job 2 failed: log $sweep/2/soma.log" out1.txt ||
  { cat out1.txt; fail "the failure is not listed with its log"; }
for n in 0 1 2 3; do
  for f in .hydra/config.yaml .hydra/hydra.yaml .hydra/overrides.yaml soma.log \
           slurm_exit_status; do
    [[ -f $sweep/$n/$f ]] || fail "job $n has no $f"
  done
  ls "$sweep/$n"/slurm-*_"$n".out "$sweep/$n"/slurm-*_"$n".err >/dev/null 2>&1 ||
    fail "job $n has no SLURM stdout/stderr beside its log"
  expected=0; [[ $n == 2 ]] && expected=1
  [[ $(cat "$sweep/$n/slurm_exit_status") == "$expected" ]] ||
    fail "job $n exit status $(cat "$sweep/$n/slurm_exit_status"), expected $expected"
  grep -q "array_task_id: '$n'" "$sweep/$n/.hydra/hydra.yaml" ||
    fail "job $n's provenance has no SLURM array task id"
  grep -q "node: localhost" "$sweep/$n/.hydra/hydra.yaml" ||
    fail "job $n's provenance has no SLURM node"
done
grep -q "failing at step 1" "$sweep/2/soma.log" || fail "job 2's log lacks its error"
grep -q "failing at step 1" "$sweep"/2/slurm-*_2.err ||
  fail "job 2's SLURM stderr lacks its error"
step "1. wait=true: $(csv_status)"

# --- 2. the same command again: only the failed job --------------------------
log0=$(stat -c %Y.%s "$sweep/0/soma.log")
set +e
"$soma" "${sweep_args[@]}" >out2.txt 2>&1
rc=$?
set -e
[[ $rc -eq 1 ]] || { cat out2.txt; fail "re-run exited $rc"; }
grep -q "(jobs 2);" out2.txt || { cat out2.txt; fail "the re-run did not submit only job 2"; }
[[ $(csv_status) == "0,done,1 1,done,1 2,failed,2 3,done,1 " ]] ||
  fail "ledger after the re-run: $(csv_status)"
[[ $(stat -c %Y.%s "$sweep/0/soma.log") == "$log0" ]] || fail "job 0's log was rewritten"
[[ $(grep -c "array_job_id" "$sweep/.slurm/submissions.yaml") == 2 ]] ||
  fail "expected two submissions"
step "2. re-run resubmitted only job 2: $(csv_status)"

# --- 3. bad input: one line, exit 1, ledger unchanged ------------------------
cp "$sweep/jobs.yaml" ledger_before.yaml
expect_error() {  # expect_error NAME PATTERN -- command...
  local name=$1 pattern=$2
  shift 3
  set +e
  "$@" >err.txt 2>&1
  local rc=$?
  set -e
  [[ $rc -eq 1 ]] || { cat err.txt; fail "$name: exit $rc, not 1"; }
  grep -v "\]\[soma\]\[INFO\]" err.txt > err_lines.txt || true
  [[ $(wc -l < err_lines.txt) -eq 1 ]] || { cat err.txt; fail "$name: not one error line"; }
  grep -q "$pattern" err_lines.txt || { cat err.txt; fail "$name: no '$pattern'"; }
  cmp -s ledger_before.yaml "$sweep/jobs.yaml" || fail "$name changed the ledger"
  [[ $(cat "$sweep/2/slurm_exit_status") == 1 ]] ||
    fail "$name lost job 2's exit status"
  step "3. $name: $(cat err_lines.txt)"
}
mkdir -p nobin
expect_error "sbatch missing" "needs 'sbatch' on PATH" -- \
  env PATH="$work/run/nobin" "$soma" "${sweep_args[@]}"
sed 's/^SlurmctldPort=.*/SlurmctldPort=1/' "$SLURM_CONF" > unreachable.conf
expect_error "controller unreachable" "Unable to contact slurm controller" -- \
  env SLURM_CONF="$work/run/unreachable.conf" "$soma" "${sweep_args[@]}"
expect_error "partition rejected" "Invalid partition name specified" -- \
  "$soma" "${sweep_args[@]}" hydra.launcher.partition=nosuch
expect_error "unknown launcher" "Available options in 'hydra/launcher': basic, local, slurm" -- \
  "$soma" "${sweep_args[@]}" hydra/launcher=nosuch

# --- 4. wait=false, sweep status, sweep cancel -------------------------------
# Jobs of ~30 s each (cancelled long before): with 2 CPUs, 2 run, 2 wait.
long_args=(-cn demo -m 'seed=0,1,2,3' task.steps=600 task.step_ms=50
           hydra/launcher=slurm hydra.sweep.dir="$work/run/long")
long=$work/run/long
start=$SECONDS
printed=$("$soma" "${long_args[@]}" hydra.launcher.wait=false 2>submit.txt) ||
  { cat submit.txt; fail "wait=false submission failed"; }
[[ $printed == "$long" ]] || fail "wait=false printed '$printed', not the sweep dir"
(( SECONDS - start < 10 )) || fail "wait=false took $(( SECONDS - start )) s"
for _ in $(seq 100); do
  "$soma" sweep status "$long" >status.txt || true
  grep -q "2 running, 2 pending" status.txt && break
  sleep 0.2
done
grep -q "4 jobs: 0 done, 2 running, 2 pending, 0 failed" status.txt ||
  { cat status.txt; fail "sweep status did not show 2 running, 2 pending"; }
step "4. wait=false + sweep status: $(tail -1 status.txt)"
"$soma" sweep cancel "$long" >cancel.txt || { cat cancel.txt; fail "sweep cancel"; }
grep -q "Cancelled 4 job(s): 0, 1, 2, 3" cancel.txt || { cat cancel.txt; fail "sweep cancel output"; }
for _ in $(seq 100); do
  [[ -z $(squeue -h) ]] && break
  sleep 0.2
done
[[ -z $(squeue -h) ]] || fail "jobs still queued after sweep cancel: $(squeue -h)"
set +e
"$soma" sweep status "$long" >status.txt
rc=$?
set -e
[[ $rc -eq 1 ]] && grep -q "4 jobs: 0 done, 0 running, 0 pending, 4 failed" status.txt &&
  grep -q "cancelled (soma sweep cancel)" status.txt ||
  { cat status.txt; fail "sweep status after cancel (exit $rc)"; }
step "4. sweep cancel: $(tail -1 status.txt)"
# A job killed behind soma's back (plain scancel): its wrapper's exit status
# makes it failed although the ledger still said running.
killed=$work/run/killed
"$soma" -cn demo -m seed=0 task.steps=600 task.step_ms=50 hydra/launcher=slurm \
  hydra.launcher.wait=false hydra.sweep.dir="$killed" >/dev/null 2>kill_submit.txt ||
  { cat kill_submit.txt; fail "submitting the job to kill"; }
for _ in $(seq 100); do
  grep -q "status: running" "$killed/jobs.yaml" && break
  sleep 0.2
done
grep -q "status: running" "$killed/jobs.yaml" || fail "the job to kill never ran"
scancel "$(sed -n "s/.*array_job_id: *'\{0,1\}\([0-9]*\).*/\1/p" "$killed/.slurm/submissions.yaml")"
for _ in $(seq 100); do
  [[ -z $(squeue -h) ]] && break
  sleep 0.2
done
set +e
"$soma" sweep status "$killed" >status.txt
set -e
grep -q "the job exited with status 143" status.txt && grep -q "0 done, 0 running, 0 pending, 1 failed" status.txt ||
  { cat status.txt; fail "a job killed by scancel is not failed with its exit status"; }
step "4. plain scancel: $(grep 'exited' status.txt | sed 's/^ *//')"

# --- 5. wait=true interrupted with SIGINT cancels the array ------------------
int_args=(-cn demo -m 'seed=0,1' task.steps=600 task.step_ms=50
          hydra/launcher=slurm hydra.launcher.poll_interval_s=0.5
          hydra.sweep.dir="$work/run/interrupted")
: >int.txt
"$soma" "${int_args[@]}" >int.txt 2>&1 &
pid=$!
for _ in $(seq 100); do
  grep -q "0 done, 2 running" int.txt && break
  sleep 0.2
done
grep -q "0 done, 2 running" int.txt || { cat int.txt; fail "the interrupted sweep never ran"; }
kill -INT "$pid"
set +e
wait "$pid"
rc=$?
set -e
[[ $rc -ne 0 ]] || fail "the interrupted sweep exited 0"
grep -q "Interrupted: cancelling SLURM array" int.txt || { cat int.txt; fail "no cancel on SIGINT"; }
for _ in $(seq 100); do
  [[ -z $(squeue -h) ]] && break
  sleep 0.2
done
[[ -z $(squeue -h) ]] || fail "jobs still queued after SIGINT: $(squeue -h)"
grep -c "status: failed" "$work/run/interrupted/jobs.yaml" | grep -q 2 ||
  fail "the interrupted jobs are not failed in the ledger"
step "5. SIGINT cancelled the array (exit $rc)"

# --- 6. preemption: SIGUSR1 -> requeue -> resume from the checkpoint ---------
# A demo job that checkpoints every step (task.checkpoint=true) stands in for
# a training (which checkpoints every epoch): preempted with
# `scancel --signal=USR1 -b`, it is requeued, resumes and ends with the same
# metrics as an uninterrupted run.
pre=$work/run/preempt
pre_task=(seed=0 task.steps=40 task.step_ms=100 task.checkpoint=true)
"$soma" -cn demo -m "${pre_task[@]}" hydra/launcher=slurm hydra.launcher.wait=false \
  hydra.sweep.dir="$pre" >/dev/null 2>pre_submit.txt ||
  { cat pre_submit.txt; fail "submitting the preemption job"; }
array=$(sed -n "s/.*array_job_id: *'\{0,1\}\([0-9]*\).*/\1/p" "$pre/.slurm/submissions.yaml" | tail -1)
[[ -n $array ]] || fail "no array job id for the preemption job"
done_steps() { head -1 "$pre/0/demo_checkpoint.txt" 2>/dev/null | cut -d' ' -f1; }
for _ in $(seq 150); do
  (( $(done_steps || echo 0) >= 5 )) 2>/dev/null && break
  sleep 0.2
done
(( $(done_steps) >= 5 )) || fail "the preemption job did not reach step 5"
scancel --signal=USR1 -b "${array}_0"
for _ in $(seq 100); do
  squeue -h -r -o '%F_%K %T %r' | grep -q "^${array}_0 PENDING" && break
  sleep 0.2
done
squeue -h -r -o '%F_%K %T %r' | grep -q "^${array}_0 PENDING" ||
  fail "the preempted job was not requeued: $(squeue -h -r -o '%F_%K %T %r')"
stopped_at=$(done_steps)
# SLURM holds a requeued job back for cred_expire+1 s (11 s here).
for _ in $(seq 300); do
  grep -q "^0,done" "$pre/jobs.csv" 2>/dev/null && break
  sleep 0.2
done
[[ $(cut -d, -f1-3 "$pre/jobs.csv" | tail -1) == "0,done,2" ]] ||
  fail "the requeued job: $(cut -d, -f1-3 "$pre/jobs.csv" | tail -1), not 0,done,2"
grep -q "demo: resumed from step" "$pre/0/soma.log" ||
  fail "the requeued job did not resume from its checkpoint"
grep -q "requeued SLURM job" "$pre"/0/slurm-*_0.err || fail "no requeue message in SLURM's stderr"
grep -q "restart_count: '1'" "$pre/0/.hydra/hydra.yaml" ||
  fail "the requeued job's provenance has no restart count 1"
"$soma" -cn demo "${pre_task[@]}" task.step_ms=0 hydra.run.dir="$work/run/straight" \
  >straight.txt 2>&1 || { cat straight.txt; fail "the uninterrupted run"; }
cmp -s "$pre/0/metrics.yaml" "$work/run/straight/metrics.yaml" &&
  cmp -s "$pre/0/metrics.csv" "$work/run/straight/metrics.csv" ||
  fail "the preempted run's metrics differ from an uninterrupted run's"
step "6. preempted at step $stopped_at, requeued, resumed: $(grep "resumed" "$pre/0/soma.log" | sed 's/.* - //'); metrics identical to an uninterrupted run ($(tr '\n' ' ' < "$pre/0/metrics.yaml"))"

echo "slurm_test: ok (${SECONDS}s)"
