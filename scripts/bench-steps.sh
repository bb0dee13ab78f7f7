# Sourced by scripts/bench-gpu.sh and scripts/bench-gpu-papers.sh (set OUT, log and L first; L
# multiplies every step's limit): `step NAME LIMIT COMMAND...` runs COMMAND under `timeout
# LIMIT*L` into OUT/NAME.txt and appends its exit, duration and last lines to the log; then the
# machine's GPU, driver and cores are logged.
: "${XDG_RUNTIME_DIR:=/tmp}"
export XDG_RUNTIME_DIR
step() {
    name=$1
    limit=$(($2 * ${L:-1}))
    shift 2
    echo "== $name (limit ${limit}s): $*" | tee -a "$log"
    t0=$(date +%s)
    timeout "$limit" "$@" >"$OUT/$name.txt" 2>&1
    rc=$?
    echo "== $name: exit $rc after $(($(date +%s) - t0)) s" | tee -a "$log"
    tr '\r' '\n' <"$OUT/$name.txt" | grep -v '^ *$' | grep -v '^ *\[' | tail -n 50 | tee -a "$log"
}
{
    date -u
    nvidia-smi --query-gpu=name,driver_version,clocks.sm,clocks.max.sm --format=csv 2>&1
    nproc
} | tee -a "$log"
