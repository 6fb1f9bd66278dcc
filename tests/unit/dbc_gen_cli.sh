#!/usr/bin/env bash
# pmsm-dbc-gen as a user runs it: --check passes on the committed files and names what it
# cannot check (a missing file, a directory) instead of calling it out of date.
#   dbc_gen_cli.sh SOURCE_DIR PMSM_DBC_GEN_EXE
set -euo pipefail
src=$1
exe=$2
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
fail() { echo "FAIL: $*"; echo "--- output:"; cat "$work/out"; exit 1; }
# expect STATUS TEXT ARGS...: the exit status and a text of the output.
expect() {
  local want_status=$1 want_text=$2 status=0
  shift 2
  "$exe" "$@" > "$work/out" 2>&1 || status=$?
  [ "$status" -eq "$want_status" ] || fail "pmsm-dbc-gen $*: exit $status, expected $want_status"
  [ -z "$want_text" ] || grep -qF -- "$want_text" "$work/out" || fail "pmsm-dbc-gen $*: no '$want_text'"
}
"$exe" --check --dbc "$src/can/pmsm-thermal.dbc" --docs "$src/docs/protocol.md" > "$work/out" 2>&1 ||
  fail "the committed DBC and docs are not what the generator writes"
expect 1 "pmsm-dbc-gen: cannot check $work/absent.dbc: no such file" --check --dbc "$work/absent.dbc"
expect 1 "pmsm-dbc-gen: cannot check $work: is a directory" --check --dbc "$work"
expect 1 "pmsm-dbc-gen: cannot read $work: is a directory" --docs "$work"
expect 2 "pmsm-dbc-gen: --check compares files: give --dbc FILE, --docs FILE or both" --check
printf 'old\n' > "$work/stale.dbc"
expect 1 "pmsm-dbc-gen: $work/stale.dbc is out of date" --check --dbc "$work/stale.dbc"
"$exe" --dbc "$work/stale.dbc" > "$work/out" 2>&1 || fail "cannot write a DBC"
expect 0 "" --check --dbc "$work/stale.dbc"
expect 0 "pmsm-dbc-gen " --version
expect 0 "usage: pmsm-dbc-gen" --help
# --help, --version and the DBC on standard output to a full disk: exit 1, naming it.
for args in --help --version ""; do
  status=0
  # shellcheck disable=SC2086
  "$exe" $args > /dev/full 2> "$work/out" || status=$?
  [ "$status" -eq 1 ] && grep -qF "pmsm-dbc-gen: cannot write standard output (" "$work/out" ||
    fail "pmsm-dbc-gen $args > /dev/full: exit $status, expected 1 naming it"
  # --help and --version are written in one go: the reason is the failed write's own.
  if [ -n "$args" ]; then
    grep -qF "pmsm-dbc-gen: cannot write standard output (No space left on device)" "$work/out" ||
      fail "pmsm-dbc-gen $args > /dev/full: the reason is not the write's: $(cat "$work/out")"
  fi
done
echo "dbc_gen_cli: ok"
