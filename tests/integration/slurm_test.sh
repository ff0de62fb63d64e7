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
#      of an uninterrupted run;
#   7. a tiny real training preempted the same way resumes from last.pt and
#      ends with the metrics.csv of an uninterrupted run;
#   8. `soma reproduce <spec> hydra/launcher=slurm`: the models as one array,
#      a failing model reported with its log, the re-run submitting only it;
#   9. reproduce with wait=false, a re-run that waits for the queued models
#      instead of submitting them again, and a model preempted mid-training.
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

# A run killed before its EXIT trap (CTest's timeout sends SIGKILL) leaves its
# daemons holding the cluster's ports: stop those of earlier runs first.
for stale in /tmp/soma_slurm_test.*/cluster; do
  [[ -d $stale ]] || continue
  echo "slurm_test: stopping the cluster an earlier run left in $stale"
  bash "$source/scripts/slurm_local.sh" stop "$stale" || true
  rm -rf "${stale%/cluster}"
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

# --- 7. a real training preempted: checkpointed mid-epoch, requeued, resumed -
# A tiny `soma train` (4 epochs of ~1 s) through the SLURM launcher, preempted
# with `scancel --signal=USR1 -b` after its first epoch: the wrapper passes
# SIGUSR1 on to soma, whose trainer checkpoints at the next batch (mid-epoch:
# batch index, the epoch's loss sum) and stops; the wrapper requeues the task,
# which resumes from checkpoints/last.pt. Its metrics.csv must equal an
# uninterrupted run's in every column but the two machine-dependent ones
# (wall_s, frames_per_s). (A signal that lands during validation checkpoints
# at the epoch's end instead; the step says which happened.)
tr=$work/run/train_preempt
tr_task=(seed=0 scale=cpu train.max_epochs=4 train.train_frames=6144
         train.val_frames=256 train.batch_size=32 model.d_model=10 model.hidden=16
         model.backbone.num_layers=1 threads=1 train.progress=false)
"$soma" train -m "${tr_task[@]}" hydra/launcher=slurm hydra.launcher.wait=false \
  hydra.sweep.dir="$tr" >/dev/null 2>tr_submit.txt ||
  { cat tr_submit.txt; fail "submitting the training to preempt"; }
array=$(sed -n "s/.*array_job_id: *'\{0,1\}\([0-9]*\).*/\1/p" "$tr/.slurm/submissions.yaml" | tail -1)
[[ -n $array ]] || fail "no array job id for the training"
epochs_done() { tail -n +2 "$tr/0/metrics.csv" 2>/dev/null | wc -l; }
for _ in $(seq 600); do
  (( $(epochs_done) >= 1 )) && break
  sleep 0.1
done
(( $(epochs_done) >= 1 && $(epochs_done) < 4 )) ||
  fail "the training was not between epochs 1 and 4 ($(epochs_done) epochs done)"
scancel --signal=USR1 -b "${array}_0"
for _ in $(seq 100); do
  squeue -h -r -o '%F_%K %T' | grep -q "^${array}_0 PENDING" && break
  sleep 0.2
done
squeue -h -r -o '%F_%K %T' | grep -q "^${array}_0 PENDING" ||
  fail "the preempted training was not requeued: $(squeue -h -r -o '%F_%K %T')"
stopped_epochs=$(epochs_done)
for _ in $(seq 600); do
  grep -q "^0,done" "$tr/jobs.csv" 2>/dev/null && break
  grep -q "^0,failed" "$tr/jobs.csv" 2>/dev/null && break
  sleep 0.2
done
[[ $(cut -d, -f1-3 "$tr/jobs.csv" | tail -1) == "0,done,2" ]] ||
  fail "the requeued training: $(cut -d, -f1-3 "$tr/jobs.csv" | tail -1), not 0,done,2"
grep -q "train: SIGUSR1: checkpointed" "$tr/0/soma.log" ||
  fail "the training did not checkpoint on SIGUSR1"
resumed=$(grep -o "train: resumed from .* after epoch [0-9]*[a-z0-9 ]*" "$tr/0/soma.log" |
          sed 's/.* after //') ||
  fail "the requeued training did not resume from its checkpoint"
[[ $resumed =~ ^epoch\ [123]( |$) ]] || fail "resumed after '$resumed', not in epochs 1-3"
grep -q "requeued SLURM job" "$tr"/0/slurm-*_0.err || fail "no requeue message for the training"
"$soma" train "${tr_task[@]}" hydra.run.dir="$work/run/train_straight" \
  >train_straight.txt 2>&1 || { cat train_straight.txt; fail "the uninterrupted training"; }
cut -d, -f1-9 "$tr/0/metrics.csv" > tr_preempted.csv
cut -d, -f1-9 "$work/run/train_straight/metrics.csv" > tr_straight.csv
[[ $(wc -l < tr_straight.csv) == 5 ]] || fail "the uninterrupted training has not 4 epochs"
# Numerically: every value of the 9 deterministic columns, all 4 epochs.
max_diff=$(paste -d, tr_preempted.csv tr_straight.csv | tail -n +2 | awk -F, '
  NF != 18 { print "columns"; exit }
  { for (i = 1; i <= 9; ++i) { d = $i - $(i + 9); if (d < 0) d = -d; if (d > m) m = d } }
  END { if (NR != 4) print "rows " NR; else printf "%g\n", m }')
[[ $max_diff == 0 ]] ||
  { paste -d'\n' tr_preempted.csv tr_straight.csv >&2;
    fail "the preempted training's metrics.csv differs from an uninterrupted run's (max |diff| $max_diff)"; }
step "7. training preempted after $stopped_epochs epoch(s): $(grep -o 'SIGUSR1: checkpointed [a-z0-9/ ]*[a-z0-9]' "$tr/0/soma.log"); requeued, resumed after ${resumed% }; metrics.csv (4 epochs x 9 columns) equal to an uninterrupted run's (max |diff| $max_diff; last row $(tail -1 tr_straight.csv | cut -d, -f1-5))"

# --- 8. soma reproduce <name> hydra/launcher=slurm --------------------------
# A 3-model spec with tiny models on a 120-frame cut of a real HDM05 take:
# the corruption runs here, the models go to SLURM as one array (each task
# runs its model's train, label and eval), the table is written here. The
# third variant's training is refused (batch larger than an epoch): it fails
# with its log, the others finish; the same command again submits only it.
rp=$work/run/repro
shared=${SOMA_SHARED_DATA:-$source/../shared/data}
take=$shared/c3d/HDM_mm_01-02_03_120.c3d
[[ -f $take ]] || fail "no $take for the reproduction (set SOMA_SHARED_DATA)"
mkdir -p "$rp/ablations" "$rp/data/c3d"
"$soma" trim task.input="$take" task.frames=120 hydra.run.dir="$rp/trim" >trim.txt 2>&1 ||
  { cat trim.txt; fail "soma trim"; }
cp "$rp"/trim/*.c3d "$rp/data/c3d/short.c3d"
cat > "$rp/ablations/mini.yaml" <<'EOF'
name: mini
title: "Mini reproduction on SLURM"
seeds: 1
tests:
  short: {label: "HDM05 cut", take: c3d/short.c3d, setting: OC_05_G_03_BT_00}
variants:
  - {name: base, label: "Base"}
  - {name: lsm, label: "Log-Softmax", overrides: [normalization=log_softmax]}
  - {name: broken, label: "Broken", overrides: [train.batch_size=4096]}
claims:
  - {text: "Sinkhorn beats Log-Softmax", test: short, better: base, worse: lsm}
differences: ["tiny models"]
EOF
repro_args=(reproduce mini task.ablations_dir="$rp/ablations" task.root="$rp/root"
            task.results_dir="$rp/results" task.data_dir="$rp/data"
            'task.budget=["scale=cpu","train.max_epochs=1","train.train_frames=64","train.val_frames=32","train.batch_size=32","model.d_model=10","model.hidden=16","model.backbone.num_layers=1"]'
            hydra/launcher=slurm hydra.launcher.poll_interval_s=0.5
            hydra.launcher.cpus_per_task=1)
start=$SECONDS
set +e
"$soma" "${repro_args[@]}" hydra.run.dir="$rp/run1" >repro1.txt 2>&1
rc=$?
set -e
repro1_s=$(( SECONDS - start ))
[[ $rc -eq 1 ]] || { cat repro1.txt; fail "reproduce with a failing model exited $rc, not 1"; }
grep -q "submitted SLURM array job [0-9]* (3 models: 0-2)" repro1.txt ||
  { cat repro1.txt; fail "the reproduction did not submit its 3 models as one array"; }
ledger=$(ls -d "$rp"/root/mini-*)
repro_status() { cut -d, -f1-3 "$ledger/jobs.csv" | tail -n +2 | tr '\n' ' '; }
[[ $(repro_status) == "0,done,1 1,done,1 2,failed,1 " ]] ||
  { cat repro1.txt; fail "reproduction ledger: $(repro_status)"; }
grep -q "broken seed 0: train broken seed 0 failed: .*batch_size.*(log: .*/stdout.txt); the job exited with status 1; see .*/slurm-[0-9]*_2.err" repro1.txt ||
  { cat repro1.txt; fail "the failed model is not reported with its command, log and SLURM stderr"; }
err2=$(ls "$ledger"/.slurm/tasks/2/slurm-*_2.err)
grep -q "train broken seed 0 failed: .*batch_size.*(log: .*/stdout.txt)" "$err2" ||
  { cat "$err2"; fail "the failed model's stderr does not name the command, error and log"; }
md=$rp/results/mini.md
grep -q "| Base | HDM05 cut | " "$md" && grep -q "| Log-Softmax | HDM05 cut | " "$md" ||
  { cat "$md"; fail "the table lacks the models trained on SLURM"; }
for n in 0 1; do
  dir=$(readlink -f "$ledger/.slurm/tasks/$n")
  [[ $(cat "$dir/slurm_exit_status") == 0 ]] || fail "model $n: exit status $(cat "$dir/slurm_exit_status")"
  grep -q "node: localhost" "$dir/.hydra/hydra.yaml" ||
    fail "model $n's training provenance has no SLURM node"
  ls "$dir"/tests/*/eval/metrics.yaml >/dev/null || fail "model $n was not evaluated"
done
stamp=$(stat -c %Y.%s "$(readlink -f "$ledger/.slurm/tasks/0")/metrics.yaml")
step "8. reproduce on SLURM in ${repro1_s}s: $(repro_status); $(grep -o 'SLURM array [0-9]* ended .*' repro1.txt)"
start=$SECONDS
set +e
"$soma" "${repro_args[@]}" hydra.run.dir="$rp/run2" >repro2.txt 2>&1
rc=$?
set -e
[[ $rc -eq 1 ]] || { cat repro2.txt; fail "the reproduction's re-run exited $rc"; }
grep -q "submitted SLURM array job [0-9]* (1 models: 2)" repro2.txt ||
  { cat repro2.txt; fail "the re-run did not submit only the failed model"; }
[[ $(repro_status) == "0,done,1 1,done,1 2,failed,2 " ]] ||
  fail "reproduction ledger after the re-run: $(repro_status)"
[[ $(stat -c %Y.%s "$(readlink -f "$ledger/.slurm/tasks/0")/metrics.yaml") == "$stamp" ]] ||
  fail "the re-run retrained model 0"
step "8. re-run in $(( SECONDS - start ))s submitted only the failed model: $(repro_status)"

# --- 9. reproduce: wait=false, a re-run that waits, a model preempted -------
# The two good variants with 12-epoch trainings, submitted with wait=false; the
# same command with wait=true does not submit them again but waits for them;
# meanwhile model 0 is preempted after its first epoch (the chain script
# passes the wrapper's SIGUSR1 on to the training, which checkpoints and
# stops), requeued and resumed from last.pt; both models end done and the table has both rows.
# (An epoch of this tiny model takes well under a second: with 4 epochs, on a
# machine busy with a training, model 0 once ended before the signal reached
# it, and was not requeued.)
long_repro=(reproduce mini task.ablations_dir="$rp/ablations" task.root="$rp/root_long"
            task.results_dir="$rp/results_long" task.data_dir="$rp/data"
            hydra/launcher=slurm hydra.launcher.poll_interval_s=0.5
            hydra.launcher.cpus_per_task=1 'task.variants=[base,lsm]'
            'task.budget=["scale=cpu","train.max_epochs=12","train.train_frames=3072","train.val_frames=256","train.batch_size=32","model.d_model=10","model.hidden=16","model.backbone.num_layers=1","train.progress=false"]')
start=$SECONDS
"$soma" "${long_repro[@]}" hydra.launcher.wait=false hydra.run.dir="$rp/run3" >repro3.txt 2>&1 ||
  { cat repro3.txt; fail "reproduce with wait=false"; }
(( SECONDS - start < 10 )) || fail "reproduce wait=false took $(( SECONDS - start )) s"
grep -q "submitted SLURM array job [0-9]* (2 models: 0-1)" repro3.txt ||
  { cat repro3.txt; fail "reproduce wait=false did not submit the 2 models"; }
"$soma" "${long_repro[@]}" hydra.run.dir="$rp/run4" >repro4.txt 2>&1 &
waiter=$!
long_ledger=$(ls -d "$rp"/root_long/mini-*)
m0=$(readlink -f "$long_ledger/.slurm/tasks/0")
for _ in $(seq 600); do
  (( $(tail -n +2 "$m0/metrics.csv" 2>/dev/null | wc -l) >= 1 )) && break
  sleep 0.1
done
(( $(tail -n +2 "$m0/metrics.csv" | wc -l) < 12 )) || fail "model 0 finished before it was preempted"
array=$(sed -n "s/.*array_job_id: *'\{0,1\}\([0-9]*\).*/\1/p" "$long_ledger/.slurm/submissions.yaml" | tail -1)
scancel --signal=USR1 -b "${array}_0"
set +e
wait "$waiter"
rc=$?
set -e
[[ $rc -eq 0 ]] || { cat repro4.txt; fail "the waiting re-run exited $rc"; }
# Model 0 is in SLURM's queue when the re-run looks (it is preempted and
# requeued); model 1's short training may already have ended on a busy
# machine, which the fresh-machine check of 2026-12-05 hit ("models 0 are
# still ..."): either way nothing is submitted again (below).
grep -Eq "models 0(-1)? are still in SLURM's queue from an earlier submission" repro4.txt ||
  { cat repro4.txt; fail "the waiting re-run did not recognise the queued models"; }
! grep -q "submitted SLURM array" repro4.txt || fail "the waiting re-run submitted again"
grep -q "requeued SLURM job" "$m0"/slurm-*_0.err || fail "model 0 was not requeued"
grep -q "train base seed 0 stopped by signal 10" "$m0"/slurm-*_0.err ||
  fail "model 0's chain did not pass SIGUSR1 on to its training"
grep -q "train: SIGUSR1: checkpointed" "$m0/soma.log" ||
  fail "model 0's training did not checkpoint on SIGUSR1"
resumed=$(grep -o "train: resumed from .* after epoch [0-9]*[a-z0-9 ]*[a-z0-9]" "$m0/soma.log" | sed 's/.* after //') ||
  fail "model 0's training did not resume from its checkpoint"
[[ $(cut -d, -f1-2 "$long_ledger/jobs.csv" | tail -n +2 | tr '\n' ' ') == "0,done 1,done 2,pending " ]] ||
  fail "ledger after the preempted reproduction: $(cut -d, -f1-3 "$long_ledger/jobs.csv")"
grep -q "| Base | HDM05 cut | " "$rp/results_long/mini.md" ||
  fail "the table lacks the preempted model"
step "9. reproduce wait=false + waiting re-run, model 0 preempted and resumed after $resumed: done in $(( SECONDS - start ))s"

echo "slurm_test: ok (${SECONDS}s)"
