# Source this to get the built environment: the venv (when there is one) and install/setup.bash.
# Used by the Makefile; `. .venv/bin/activate && . install/setup.bash` by hand does the same.
if [ -f .venv/bin/activate ]; then
  . .venv/bin/activate
fi
# setup.bash reads unset variables; relax nounset while sourcing it.
case $- in *u*) _dxl_nounset=1; set +u ;; *) _dxl_nounset= ;; esac
. install/setup.bash
[ -n "$_dxl_nounset" ] && set -u
unset _dxl_nounset
