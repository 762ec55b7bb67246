# Source this file (bash) to use the workspace: `source ./env.sh`.
# Activates .venv, makes ament find the message packages installed as wheels, and sources
# the colcon workspace so every console script (globloc, atacama_sim, ...) is on PATH.
_here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
if [ ! -f "$_here/.venv/bin/activate" ] || [ ! -f "$_here/ros2_ws/install/setup.bash" ]; then
  echo "env.sh: workspace not set up; run 'make setup' in $_here first" >&2
  return 1 2>/dev/null || exit 1
fi
source "$_here/.venv/bin/activate"
export AMENT_PREFIX_PATH="$VIRTUAL_ENV${AMENT_PREFIX_PATH:+:$AMENT_PREFIX_PATH}"
# colcon's setup scripts reference unset variables; source them without nounset.
_nounset=$(set +o | grep nounset); set +u
source "$_here/ros2_ws/install/setup.bash"
eval "$_nounset"
# There is no `ros2 run`: put each package's executables (install/<pkg>/lib/<pkg>) on PATH.
for _d in "$_here"/ros2_ws/install/*/lib/*/; do
  case ":$PATH:" in *":${_d%/}:"*) ;; *) PATH="${_d%/}:$PATH" ;; esac
done
export PATH
unset _here _nounset _d
