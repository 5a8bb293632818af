# Source this to get the built environment: the venv (when there is one) and install/setup.bash.
# Used by the Makefile; `. .venv/bin/activate && . install/setup.bash` by hand does the same
# (install/setup.bash chains .venv/ros_compat, where make setup built control_msgs).
if [ -f .venv/bin/activate ]; then
  . .venv/bin/activate
fi
# setup.bash reads unset variables; relax nounset while sourcing it.
case $- in *u*) _dxl_nounset=1; set +u ;; *) _dxl_nounset= ;; esac
# The control_msgs stand-in, when make setup built one (tools/setup_env.sh).
if [ -f .venv/ros_compat/local_setup.bash ]; then
  . .venv/ros_compat/local_setup.bash
fi
. install/setup.bash
[ -n "$_dxl_nounset" ] && set -u
unset _dxl_nounset
