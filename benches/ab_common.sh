# Shared by benches/ab_build.sh and benches/ab_vector.sh (sourced, not run).
# ab_example REV EXAMPLE: build equigym-envs' example EXAMPLE at git revision REV in a temporary
# worktree with its own target directory, cached under ~/.cache/equigym-ab/<commit> (a second
# call does not rebuild it), and print the cached binary's path.
ab_example() {
  local commit cache bin wt
  commit=$(git rev-parse --short "$1")
  cache=${HOME}/.cache/equigym-ab/$commit
  bin=$cache/$2
  if [[ ! -x $bin ]]; then
    wt=$(mktemp -d /tmp/equigym-ab.XXXXXX)
    git worktree add -q --detach "$wt" "$commit"
    (cd "$wt" && CARGO_TARGET_DIR=$cache/target cargo build --release -q -p equigym-envs --example "$2")
    mkdir -p "$cache"
    cp "$cache/target/release/examples/$2" "$bin"
    git worktree remove --force "$wt"
  fi
  echo "$bin"
}
