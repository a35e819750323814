#!/usr/bin/env bash
# Runs the Slurm job array of docs/cluster.md ("Slurm job array", render-sweep.sbatch) on a real
# Slurm started on this machine alone: installs slurm-wlm and munge if missing, starts munged,
# slurmctld and slurmd with every file in a temporary directory, submits the script from the
# docs unchanged (sbatch options override its size), and checks a 12-job sweep:
#   1. four array tasks render every job once;
#   2. from scratch again, one task is cancelled in the middle (scancel JOB_TASK), the same range
#      is resubmitted, and only the missing jobs are rendered.
# Stops every daemon it started (by PID) and prints PASS or FAIL. Runs as root (re-runs itself
# with sudo otherwise). PENUMBRA_BIN: the binary to test (default: build/penumbra of the repo).
set -euo pipefail
start_time=$SECONDS
root="$(cd "$(dirname "$0")/.." && pwd)"
bin="${PENUMBRA_BIN:-$root/build/penumbra}"

say() { echo "slurm-check: [$((SECONDS - start_time)) s] $*"; }
fail() { echo "slurm-check: error: $*" >&2; exit 1; }
policy=""    # a policy-rc.d of ours, while apt-get runs
early_exit() {    # until the daemons start (then cleanup takes over)
    local status=$?
    [ -z "$policy" ] || rm -f "$policy"
    [ "$status" -eq 0 ] || echo "slurm-check: FAIL ($((SECONDS - start_time)) s)"
}
trap early_exit EXIT

if [ "$(id -u)" -ne 0 ]; then
    command -v sudo >/dev/null || fail "must run as root (slurmd starts jobs as root) and sudo is missing"
    exec sudo --preserve-env=PENUMBRA_BIN "$0" "$@"
fi

[ -x "$bin" ] || fail "no penumbra binary at '$bin' (build it, or set PENUMBRA_BIN)"
bin="$(realpath "$bin")"
doc="$root/docs/cluster.md"
frames=12
tasks=4

# --- Install Slurm and munge (no service is started: a temporary policy-rc.d refuses it) ----
missing=()
for p in slurm-wlm munge; do
    dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if [ ${#missing[@]} -gt 0 ]; then
    say "installing ${missing[*]}"
    if [ ! -e /usr/sbin/policy-rc.d ]; then
        policy=/usr/sbin/policy-rc.d
        printf '#!/bin/sh\nexit 101\n' > "$policy"
        chmod 755 "$policy"
    fi
    ok=1
    apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq \
        --no-install-recommends "${missing[@]}" >/dev/null || ok=0
    [ -z "$policy" ] || rm -f "$policy"
    policy=""
    [ "$ok" = 1 ] || fail "apt-get install ${missing[*]} failed"
fi
for c in munged munge slurmctld slurmd sbatch squeue scontrol scancel sinfo; do
    command -v "$c" >/dev/null || fail "'$c' not found after installing slurm-wlm and munge"
done
# Slurm's commands wait a long time for a slurmctld that is gone: give each call 30 s at most.
for c in sbatch squeue scontrol scancel sinfo; do
    eval "$c() { timeout 30 $(command -v "$c") \"\$@\"; }"
done

# --- Temporary tree: daemons' files, the work directory the job array runs in ---------------
tmp="$(mktemp -d /tmp/slurm-check.XXXXXX)"
chmod 755 "$tmp"    # munged wants its socket's directory reachable by everyone
mkdir -p "$tmp/munge" "$tmp/state" "$tmp/spool" "$tmp/run" "$tmp/log" "$tmp/bin" "$tmp/work/sweep"
conf="$tmp/slurm.conf"
work="$tmp/work"
export SLURM_CONF="$conf"
cp "$bin" "$tmp/bin/penumbra"    # a copy: a rebuild during the check does not swap it mid-run
# The image module (OpenImageIO, docs/architecture.md) goes with it: the program looks next to
# itself.
module="$(dirname "$bin")/penumbra_image_oiio.so"
[ -f "$module" ] || fail "no image module at '$module' (build the repository's targets)"
cp "$module" "$tmp/bin/"
export PATH="$tmp/bin:$PATH"    # sbatch passes the environment on: the job finds `penumbra`

# Daemons and job processes already running (another Slurm or munge): not ours, not touched.
ps_named() { local n; for n in munged slurmctld slurmd slurmstepd; do pgrep -x "$n" || true; done; }
before="$(ps_named | xargs)"
pids=()        # daemons started here, stopped in reverse order
jobids=()      # arrays submitted here, cancelled on exit

ours_left() {    # processes of ours still alive: new daemons/steps, or a cwd under $tmp
    local p cwd
    for p in $(ps_named); do
        case " $before " in *" $p "*) continue ;; esac
        echo "$p"
    done
    for p in $(ls /proc | grep -E '^[0-9]+$'); do
        [ "$p" != $$ ] || continue
        cwd="$(readlink "/proc/$p/cwd" 2>/dev/null)" || continue
        case "$cwd" in "$tmp"|"$tmp"/*) echo "$p" ;; esac
    done
}

exec 3>&1 4>&2    # cleanup's messages go here, also when a signal comes in a redirected command
cleanup() {
    local status=$? p i
    trap - EXIT
    set +eu
    exec 1>&3 2>&4
    if [ ${#jobids[@]} -gt 0 ] && kill -0 "${pids[1]}" 2>/dev/null; then    # slurmctld is up
        scancel "${jobids[@]}" 2>/dev/null
        for ((i = 0; i < 40; i++)); do
            [ -z "$(squeue -h -o %i 2>/dev/null)" ] && break
            sleep 0.5
        done
    fi
    for ((i = ${#pids[@]} - 1; i >= 0; i--)); do
        kill "${pids[i]}" 2>/dev/null
    done
    for p in "${pids[@]}"; do
        for ((i = 0; i < 40; i++)); do kill -0 "$p" 2>/dev/null || break; sleep 0.25; done
        kill -0 "$p" 2>/dev/null && { say "daemon $p did not stop on SIGTERM: SIGKILL"; kill -9 "$p"; }
        wait "$p" 2>/dev/null
    done
    for ((i = 0; i < 20; i++)); do    # processes take a moment to go
        left="$(ours_left | sort -u | xargs)"
        [ -n "$left" ] || break
        sleep 0.25
    done
    if [ -n "$left" ]; then
        say "still running after stopping Slurm:"
        for p in $left; do
            echo "    $p ($(readlink /proc/$p/cwd)): $(tr '\0' ' ' < /proc/$p/cmdline)"
        done
        status=1
    else
        say "nothing left running (munged, slurmctld, slurmd, slurmstepd, job processes)"
    fi
    if [ "$status" -ne 0 ]; then
        for f in "$tmp"/log/*.log "$work"/logs/*.log; do
            [ -f "$f" ] || continue
            echo "--- last lines of $f"
            tail -n 15 "$f"
        done
        say "files kept in $tmp"
        echo "slurm-check: FAIL ($((SECONDS - start_time)) s)"
    else
        rm -rf "$tmp"
        echo "slurm-check: PASS ($((SECONDS - start_time)) s)"
    fi
    exit "$status"
}
trap cleanup EXIT
trap 'exit 130' INT TERM

wait_until() {    # SECONDS WHAT COMMAND...: polls COMMAND until it succeeds
    local limit=$((SECONDS + $1)) after=$1 what=$2 p
    shift 2
    until "$@" >/dev/null 2>&1; do
        [ "$SECONDS" -lt "$limit" ] || fail "timed out after ${after} s waiting for $what"
        for p in "${pids[@]}"; do
            kill -0 "$p" 2>/dev/null || fail "$(ps -o comm= -p "$p" 2>/dev/null || echo "daemon $p") exited (see $tmp/log)"
        done
        sleep 0.2
    done
}

# --- munged ------------------------------------------------------------------------------------
head -c 1024 /dev/urandom > "$tmp/munge/munge.key"
chmod 400 "$tmp/munge/munge.key"
socket="$tmp/munge/munge.socket"
munged --foreground --key-file="$tmp/munge/munge.key" --socket="$socket" \
    --pid-file="$tmp/run/munged.pid" --log-file="$tmp/log/munged.log" \
    --seed-file="$tmp/munge/munge.seed" > "$tmp/log/munged.out" 2>&1 &
pids+=($!)
munge_ok() { timeout 10 munge -S "$socket" -n | timeout 10 unmunge -S "$socket"; }
wait_until 20 "munged" munge_ok

# --- slurm.conf: one node, this machine's cores, a modest memory ------------------------------
host="$(hostname -s)"
cpus="$(nproc)"
mem_mb=$(( $(awk '/^MemTotal:/ {print $2}' /proc/meminfo) / 1024 / 2 ))
cat > "$conf" <<EOF
ClusterName=penumbracheck
SlurmctldHost=$host(127.0.0.1)
SlurmctldPort=16817
SlurmdPort=16818
SlurmUser=root
SlurmdUser=root
AuthType=auth/munge
CredType=cred/munge
AuthInfo=socket=$socket
StateSaveLocation=$tmp/state
SlurmdSpoolDir=$tmp/spool
SlurmctldPidFile=$tmp/run/slurmctld.pid
SlurmdPidFile=$tmp/run/slurmd.pid
SlurmctldLogFile=$tmp/log/slurmctld.log
SlurmdLogFile=$tmp/log/slurmd.log
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
JobAcctGatherType=jobacct_gather/none
AccountingStorageType=accounting_storage/none
JobCompType=jobcomp/none
SchedulerType=sched/backfill
SelectType=select/cons_tres
SelectTypeParameters=CR_CPU_Memory
MpiDefault=none
ReturnToService=2
MailProg=/bin/true
MinJobAge=600
KillWait=5
NodeName=$host NodeAddr=127.0.0.1 CPUs=$cpus RealMemory=$mem_mb State=UNKNOWN
PartitionName=check Nodes=$host Default=YES MaxTime=INFINITE State=UP
EOF

# --- slurmctld, slurmd (niced: the jobs inherit slurmd's priority) ----------------------------
slurmctld -D -f "$conf" > "$tmp/log/slurmctld.out" 2>&1 &
pids+=($!)
ctld_up() { scontrol ping | grep -q UP; }
wait_until 30 "slurmctld to answer (scontrol ping)" ctld_up
nice -n 10 slurmd -D -f "$conf" > "$tmp/log/slurmd.out" 2>&1 &
pids+=($!)
node_idle() { sinfo -h -n "$host" -o %t | grep -qx idle; }
wait_until 30 "node $host to be idle" node_idle
say "Slurm $(sinfo -V | awk '{print $2}') up: node $host, $cpus CPUs, ${mem_mb} MB, files in $tmp"

# --- The job script, verbatim from the docs --------------------------------------------------
awk '/^## Slurm job array/ {s = 1; next}
     s == 1 && /^```bash$/ {s = 2; next}
     s == 2 && /^```$/ {exit}
     s == 2 {print}' "$doc" > "$work/render-sweep.sbatch"
head -n 1 "$work/render-sweep.sbatch" | grep -q '^#!' && grep -q '^#SBATCH --array' "$work/render-sweep.sbatch" \
    || fail "no sbatch script found after '## Slurm job array' in $doc"
say "render-sweep.sbatch: $(wc -l < "$work/render-sweep.sbatch") lines from docs/cluster.md"

# --- A sweep of 12 tiny frames (32 x 32, ~0.5-1 s each: the reference method, 8192 rays) ------
cat > "$work/sweep/manifest.json" <<EOF
{
  "defaults": {"width": 32, "height": 32, "method": "reference", "samples": 8192,
               "set": {"level_set/voxel_size": 0.02}},
  "sweep": {"scene": "$root/vdb_scenes/default.json", "output": "out/frame_{frame:02d}.exr",
            "frames": $frames,
            "vary": {"lights/0/corner": {"from": [-1.5, -1, 4], "to": [0.5, -1, 4]}}}
}
EOF
mkdir -p "$work/logs"    # the script's --output=logs/...: Slurm does not create the directory

submit() {    # submits the docs' script as an array of $tasks; sets $id to the array's job id
    id="$(sbatch --parsable --array=0-$((tasks - 1)) --cpus-per-task=1 --mem=256M \
          --time=00:05:00 --chdir="$work" "$work/render-sweep.sbatch")" || fail "sbatch refused the script"
    id="${id%%;*}"
    jobids+=("$id")
}

task_states() {    # "TASK STATE EXITCODE" per array task of job $1
    scontrol -o show job "$1" | awk '{
        for (i = 1; i <= NF; i++) { split($i, kv, "="); v[kv[1]] = substr($i, length(kv[1]) + 2) }
        print v["ArrayTaskId"], v["JobState"], v["ExitCode"] }'
}

all_ended() {    # every task of array $1 is in a final state
    local states
    states="$(task_states "$1")" || return 1
    [ "$(echo "$states" | wc -l)" -eq "$tasks" ] || return 1
    ! echo "$states" | grep -qvE ' (COMPLETED|FAILED|CANCELLED|TIMEOUT|OUT_OF_MEMORY|NODE_FAIL|BOOT_FAIL|DEADLINE|PREEMPTED) '
}

expect_states() {    # JOBID CANCELLED_TASK(or -): the others must be COMPLETED with exit 0
    local id=$1 cancelled=$2 t state code
    while read -r t state code; do
        if [ "$t" = "$cancelled" ]; then
            [ "$state" = CANCELLED ] || fail "task ${id}_$t: $state, expected CANCELLED"
        else
            [ "$state" = COMPLETED ] && [ "$code" = 0:0 ] \
                || fail "task ${id}_$t: $state (exit $code), expected COMPLETED; see $work/logs/penumbra-sweep_${id}_$t.log"
        fi
    done < <(task_states "$id")
}

status_of() {    # the summaries' "INDEX STATUS" lines, sorted by index
    awk -F, 'FNR > 1 {print $1, $3}' "$work"/summaries/shard_*.csv | sort -n
}

check_summaries() {    # every job index in exactly one summary
    local want got
    want="$(seq 0 $((frames - 1)))"
    got="$(awk -F, 'FNR > 1 {print $1}' "$work"/summaries/shard_*.csv | sort -n)"
    [ "$got" = "$want" ] || fail "the summaries do not list every job once: $(echo $got)"
    say "summaries: $(ls "$work/summaries" | wc -l) shards, indices $(echo $got | tr ' ' ,), each once"
}

check_outputs() {    # all 12 images, valid, nothing else (no temporaries), accepted by --resume
    local f n img imgs=() bad=""
    n="$(find "$work/sweep/out" -type f | wc -l)"
    [ "$n" -eq $((2 * frames)) ] || fail "$n files in sweep/out, expected $frames images and their sidecars: $(ls -A "$work/sweep/out" | tr '\n' ' ')"
    for ((f = 0; f < frames; f++)); do
        img="$work/sweep/out/frame_$(printf %02d "$f").exr"
        imgs+=("$img")
        [ -f "$img" ] && [ -f "$img.job.json" ] || { bad+=" $f"; continue; }
        if command -v jq >/dev/null; then
            [ "$(jq -r .output_bytes "$img.job.json")" = "$(stat -c %s "$img")" ] || bad+=" $f"
        fi
    done
    [ -z "$bad" ] || fail "missing outputs or sidecars that do not match them, frames:$bad"
    if command -v oiiotool >/dev/null; then    # OpenImageIO reads every image
        n="$(oiiotool --info "${imgs[@]}" 2>&1 | grep -c ': *32 x *32, 3 channel')" || true
        [ "$n" -eq "$frames" ] || fail "oiiotool --info reads $n of the $frames images as 32 x 32 RGB: $(oiiotool --info "${imgs[@]}" 2>&1 | xargs)"
    fi
    # penumbra's own check: header hash, sidecar, size and content hash of every output.
    local line
    line="$(cd "$work" && nice penumbra batch sweep/manifest.json --resume --jobs 1 --quiet \
            --summary "$tmp/verify.csv" && awk -F, 'FNR > 1 {print $3}' "$tmp/verify.csv" | sort | uniq -c | xargs)" || true
    [ "$line" = "$frames skipped" ] || fail "penumbra batch --resume over the outputs: '$line', expected '$frames skipped'"
    say "outputs: $frames images 32 x 32 with sidecars, no temporaries; --resume accepts all ($line)"
}

# --- 1. The whole sweep, four array tasks ----------------------------------------------------
submit
say "run 1: array $id, tasks 0-$((tasks - 1))"
wait_until 150 "array $id to end" all_ended "$id"
expect_states "$id" -
say "run 1: $(task_states "$id" | awk '{print $1 ":" $2}' | xargs)"
check_summaries
[ "$(status_of | awk '{print $2}' | sort -u)" = rendered ] || fail "run 1 did not render every job: $(status_of | xargs)"
check_outputs
say "task 1's log (logs/penumbra-sweep_${id}_1.log):"
sed 's/^/    /' "$work/logs/penumbra-sweep_${id}_1.log"

# --- 2. From scratch, cancel one task mid-run, resubmit the same range ----------------------
rm -rf "$work/sweep/out" "$work/summaries"
submit
victim=0    # its jobs: frames 0, 4, 8, rendered in that order (one worker)
say "run 2: array $id; cancelling task ${id}_$victim once its first frame is written"
wait_until 120 "the first output of task ${id}_$victim" test -f "$work/sweep/out/frame_00.exr"
scancel "${id}_$victim"
wait_until 150 "array $id to end" all_ended "$id"
expect_states "$id" "$victim"
done_before=()
for f in 0 4 8; do
    [ -f "$work/sweep/out/frame_$(printf %02d $f).exr" ] && done_before+=("$f")
done
[ ${#done_before[@]} -lt 3 ] || fail "task ${id}_$victim finished all its frames before scancel reached it"
[ ! -e "$work/summaries/shard_$victim.csv" ] || fail "the cancelled task wrote a summary"
say "run 2: $(task_states "$id" | awk '{print $1 ":" $2}' | xargs); task $victim had frames ${done_before[*]} of 0 4 8"

submit
say "run 3: array $id, the same range again"
wait_until 150 "array $id to end" all_ended "$id"
expect_states "$id" -
check_summaries
# Run 3 renders exactly the cancelled task's missing frames and skips the rest.
want=""
for ((f = 0; f < frames; f++)); do
    s=skipped
    if [ $((f % tasks)) -eq "$victim" ] && [[ " ${done_before[*]} " != *" $f "* ]]; then s=rendered; fi
    want+="$f $s"$'\n'
done
[ "$(status_of)" = "${want%$'\n'}" ] || fail "run 3: expected$(echo "$want" | grep rendered | cut -d' ' -f1 | xargs -I{} echo -n ' {}') rendered and the rest skipped, got: $(status_of | xargs)"
say "run 3: rendered $(status_of | awk '$2 == "rendered" {print $1}' | xargs), skipped the other $(status_of | grep -c skipped)"
check_outputs
for t in $(seq 0 $((tasks - 1))); do
    [ -s "$work/logs/penumbra-sweep_${id}_$t.log" ] || fail "no log logs/penumbra-sweep_${id}_$t.log"
done
say "task log (logs/penumbra-sweep_${id}_$victim.log): $(tail -n 1 "$work/logs/penumbra-sweep_${id}_$victim.log")"
