# Shared by the plot-script checks (plot_consensus_check.sh, plot_closed_loop_check.sh):
# source it after setting `check` (the check's name, for messages).

fail() { echo "$check: FAIL: $*" >&2; exit 1; }

is_png() { [[ -s "$1" ]] && [[ "$(head -c 8 "$1" | od -An -tx1 | tr -d ' \n')" == "89504e470d0a1a0a" ]]; }

# expect_rejected WHAT PATTERN PNG -- COMMAND...: COMMAND exits 2, its stderr matches
# PATTERN (grep), and PNG was not written.
expect_rejected() {
  local what="$1" pattern="$2" png="$3"
  shift 4
  local err
  err="$(mktemp)"
  set +e
  "$@" 2> "$err"
  local status=$?
  set -e
  [[ $status -eq 2 ]] || fail "$what: exit $status, expected 2"
  grep -q "$pattern" "$err" || fail "$what: message does not match '$pattern': $(cat "$err")"
  [[ ! -e "$png" ]] || fail "$what: a PNG was written despite the malformed input"
  rm -f "$err"
}

# expect_drawn_when_ready SCRIPT FIXTURE WORK PNG_NAME: with --when-ready (how tofu runs the
# scripts) SCRIPT draws after a line "go" on standard input, and the end of the input
# instead (a run that failed first) ends it without drawing, exit 0.
expect_drawn_when_ready() {
  local script="$1" fixture="$2" work="$3" png="$4"
  cp -r "$fixture" "$work/ready"
  echo go | "$script" "$work/ready" --when-ready || fail "exit $? with --when-ready and go"
  is_png "$work/ready/$png" || fail "no PNG with --when-ready and go"
  cp -r "$fixture" "$work/never"
  "$script" "$work/never" --when-ready < /dev/null || fail "exit $? with --when-ready and no go"
  [[ ! -e "$work/never/$png" ]] || fail "drew without go"
}
