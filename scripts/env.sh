# Source this to use the venv route by hand: `source scripts/env.sh`
# (activates .venv and sets what ROS 2 needs, as the Makefile does).
_subpix_root="$(cd "$(dirname "${BASH_SOURCE[0]:-$0}")/.." && pwd)"
. "$_subpix_root/.venv/bin/activate"
export AMENT_PREFIX_PATH="$_subpix_root/.venv/subpix_prefix:$_subpix_root/.venv${AMENT_PREFIX_PATH:+:$AMENT_PREFIX_PATH}"
export RMW_IMPLEMENTATION="${RMW_IMPLEMENTATION:-rmw_fastrtps_cpp}"
export ROS_AUTOMATIC_DISCOVERY_RANGE="${ROS_AUTOMATIC_DISCOVERY_RANGE:-LOCALHOST}"
# The package's Fast DDS profile (the subpix entry points load it by themselves; exported here for other
# programs started from this shell, e.g. a camera driver: docs/design-notes.md, "Camera frames between processes")
if [ -z "${FASTRTPS_DEFAULT_PROFILES_FILE:-}${FASTDDS_DEFAULT_PROFILES_FILE:-}" ]; then
  export FASTRTPS_DEFAULT_PROFILES_FILE="$_subpix_root/config/fastdds_profile.xml"
fi
unset _subpix_root
