# Source this to use the venv route by hand: `source scripts/env.sh`
# (activates .venv and sets what ROS 2 needs, as the Makefile does).
_subpix_root="$(cd "$(dirname "${BASH_SOURCE[0]:-$0}")/.." && pwd)"
. "$_subpix_root/.venv/bin/activate"
export AMENT_PREFIX_PATH="$_subpix_root/.venv/subpix_prefix:$_subpix_root/.venv${AMENT_PREFIX_PATH:+:$AMENT_PREFIX_PATH}"
export RMW_IMPLEMENTATION="${RMW_IMPLEMENTATION:-rmw_fastrtps_cpp}"
export ROS_AUTOMATIC_DISCOVERY_RANGE="${ROS_AUTOMATIC_DISCOVERY_RANGE:-LOCALHOST}"
unset _subpix_root
